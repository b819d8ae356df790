"""What a recording is before it is diagnosed: whose, from when, how long,
and the tasks it splits into. Read from the MCAP's summary and metadata
alone (never the messages), or a CSV's name and first and last rows."""

from __future__ import annotations

import dataclasses
import datetime as dt
import os
import re
from pathlib import Path

from mcap.reader import make_reader

SUFFIXES = (".mcap", ".csv")

# 2026-11-03, 2026-11-03T06-00, 2026-11-03T06:00:30, 2026-11-03_0600
_DATE = re.compile(r"(\d{4})-(\d{2})-(\d{2})(?:[T_ ](\d{2})[-:]?(\d{2})(?:[-:]?(\d{2}))?)?")


@dataclasses.dataclass(frozen=True)
class Recording:
    path: str
    machine_id: str
    start: dt.datetime
    duration_s: float | None
    size: int
    # Where each came from: "metadata", "folder", "file name", "modified".
    machine_from: str
    start_from: str


@dataclasses.dataclass(frozen=True)
class Task:
    recording: Recording
    window_from_s: float | None = None
    window_to_s: float | None = None

    @property
    def key(self) -> tuple[str, int, float]:
        """What the results remember a task by: a recording that changed
        (a copy finished since) is a new one."""
        return (self.recording.path, self.recording.size, self.window_from_s if self.window_from_s is not None else -1.0)


def find(paths: list[str]) -> list[str]:
    """Every recording under `paths` (files as given, folders walked), sorted."""
    found = []
    for given in paths:
        p = Path(given)
        if p.is_dir():
            found += [str(f.resolve()) for f in sorted(p.rglob("*")) if f.suffix.lower() in SUFFIXES and f.is_file()]
        elif p.exists():
            found.append(str(p.resolve()))
        else:
            raise FileNotFoundError(f"{given}: no such file or folder")
    return sorted(set(found))


def date_in_name(name: str) -> dt.datetime | None:
    """An ISO date or date-time in a file's name, as UTC."""
    m = _DATE.search(name)
    if not m:
        return None
    y, mo, d, h, mi, s = (int(g) if g else 0 for g in m.groups())
    try:
        return dt.datetime(y, mo, d, h, mi, s, tzinfo=dt.timezone.utc)
    except ValueError:
        return None


def describe(path: str) -> Recording:
    """Whose recording, from when and how long. The machine: the MCAP's
    `machine_id`, else the parent folder's name. The start: a date in the
    file's name (the archive's word: a vehicle computer's clock may be
    unset), else the MCAP's `start_time`, else the file's modification
    time. Never raises for a damaged file: what it cannot read is left to
    the task, whose row will say why."""
    p = Path(path)
    stat = p.stat()
    metadata: dict[str, str] = {}
    duration = None
    if p.suffix.lower() == ".mcap":
        metadata, duration = _mcap_summary(p)
    else:
        duration = _csv_span(p)
    machine, machine_from = (metadata["machine_id"], "metadata") if metadata.get("machine_id") else (p.parent.name, "folder")
    start, start_from = date_in_name(p.stem), "file name"
    if start is None and metadata.get("start_time"):
        start, start_from = _parse_time(metadata["start_time"]), "metadata"
    if start is None:
        start, start_from = dt.datetime.fromtimestamp(stat.st_mtime, dt.timezone.utc), "modified"
    return Recording(str(p), machine, start, duration, stat.st_size, machine_from, start_from)


def tasks(recording: Recording, window_s: float | None) -> list[Task]:
    """One task per recording, or per window of a long one (the last
    window takes a remainder shorter than half a window)."""
    d = recording.duration_s
    if not window_s or d is None or d < 1.5 * window_s:
        return [Task(recording)]
    count = max(1, int(d // window_s))
    edges = [i * window_s for i in range(count)] + [d + 1.0]
    return [Task(recording, a, b) for a, b in zip(edges, edges[1:])]


def _parse_time(text: str) -> dt.datetime | None:
    try:
        t = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    return t if t.tzinfo else t.replace(tzinfo=dt.timezone.utc)


def _mcap_summary(p: Path) -> tuple[dict[str, str], float | None]:
    """The `hydractl` metadata and the span of the messages, from the
    summary section: a few kilobytes at the file's end."""
    try:
        with p.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            metadata: dict[str, str] = {}
            for record in reader.iter_metadata():
                if record.name == "hydractl":
                    metadata.update(record.metadata)
    except Exception:  # a truncated file has no summary: the task reads what is left
        return {}, None
    stats = summary.statistics if summary else None
    if stats is None or stats.message_end_time <= stats.message_start_time:
        return metadata, None
    return metadata, (stats.message_end_time - stats.message_start_time) / 1e9


def _csv_span(p: Path) -> float | None:
    """Last `t` minus the first, from the file's first and last lines."""
    try:
        with p.open("rb") as f:
            header = f.readline().decode().strip().split(",")
            first = f.readline().decode().strip().split(",")
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 4096))
            last = f.read().decode(errors="replace").strip().splitlines()[-1].split(",")
        i = header.index("t")
        return float(last[i]) - float(first[i])
    except (ValueError, IndexError, UnicodeDecodeError):
        return None
