"""The results: one Parquet table under RESULTS_DIR, a file per batch of
rows, read back whole as one dataset."""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

_PARAMS = pa.map_(pa.string(), pa.float64())

SCHEMA = pa.schema(
    [
        ("machine_id", pa.string()),
        ("recording", pa.string()),
        ("size", pa.int64()),
        ("window_from_s", pa.float64()),
        ("window_to_s", pa.float64()),
        ("start", pa.timestamp("s", tz="UTC")),
        ("start_from", pa.string()),
        ("duration_s", pa.float64()),
        ("reference", pa.string()),
        ("reference_params", _PARAMS),
        # Validation NRMSE per output: theta, p_a, p_b, pressures, overall.
        ("nrmse", _PARAMS),
        # The reference refitted to this recording: its parameters.
        ("baseline_params", _PARAMS),
        # Their standard deviations, as the fit's own Jacobian gives them.
        ("baseline_std", _PARAMS),
        # Those the data fixed only in a combination with another (|correlation|
        # above 0.95): their own trends are not named.
        ("baseline_inseparable", pa.list_(pa.string())),
        # Each effect of the catalog the test found significant.
        (
            "effects",
            pa.list_(
                pa.struct(
                    [
                        ("effect", pa.string()),
                        ("output", pa.string()),
                        ("nrmse_before", pa.float64()),
                        ("nrmse_after", pa.float64()),
                        ("params", _PARAMS),
                        ("test", pa.string()),
                        ("statistic", pa.float64()),
                        ("threshold", pa.float64()),
                    ]
                )
            ),
        ),
        ("verdict", pa.string()),
        # What hydractl warned of while reading the recording.
        ("warnings", pa.list_(pa.string())),
        ("error", pa.string()),
        ("cpu_s", pa.float64()),
        ("max_rss_mb", pa.float64()),
        ("host", pa.string()),
    ]
)


# The columns of name → value maps: dicts in a row, lists of pairs in Arrow.
MAP_COLUMNS = ("reference_params", "nrmse", "baseline_params", "baseline_std")


def _as_arrow(row: dict) -> dict:
    out = dict(row)
    for key in MAP_COLUMNS:
        if out[key] is not None:
            out[key] = list(out[key].items())
    out["effects"] = [dict(e, params=list(e["params"].items())) for e in out["effects"]]
    return out


def write(results: Path, rows: list[dict]) -> Path | None:
    """Appends `rows` as a new file of the table."""
    if not rows:
        return None
    results.mkdir(parents=True, exist_ok=True)
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%S%f")
    path = results / f"part-{stamp}-{os.getpid()}.parquet"
    table = pa.Table.from_pylist([_as_arrow(r) for r in rows], schema=SCHEMA)
    tmp = path.with_suffix(".tmp")
    pq.write_table(table, tmp)
    tmp.rename(path)  # whole or absent: a killed run leaves no half file
    return path


def read(results: Path) -> list[dict]:
    """Every row, with the maps back as dicts, in no particular order."""
    if not results.exists() or not any(results.glob("*.parquet")):
        return []
    table = ds.dataset(results, format="parquet", schema=SCHEMA).to_table()
    rows = table.to_pylist()
    for row in rows:
        for key in MAP_COLUMNS:
            if row[key] is not None:
                row[key] = dict(row[key])
        for effect in row["effects"] or []:
            effect["params"] = dict(effect["params"])
    return rows


def done(results: Path) -> set[tuple[str, int, float]]:
    """The tasks already in the table, as `Task.key` names them."""
    return {
        (r["recording"], r["size"], r["window_from_s"] if r["window_from_s"] is not None else -1.0)
        for r in read(results)
    }
