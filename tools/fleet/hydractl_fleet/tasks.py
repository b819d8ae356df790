"""One diagnosis: the `hydractl` binary run on one recording (or a window
of it) against the machine's reference model, and the row it makes. A
failure of any kind is a row with its `error`, never an exception: one bad
recording must not stop a night's run."""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
import tomllib
from pathlib import Path

from .sources import Task

# Past this a diagnosis is stuck, not slow (a minute of data takes 1-3 s).
TIMEOUT_S = 900.0


def hydractl_binary(given: str | None) -> str:
    """`--hydractl`, else `HYDRACTL`, else `hydractl` on the PATH."""
    found = given or os.environ.get("HYDRACTL") or shutil.which("hydractl")
    if not found:
        raise FileNotFoundError("no hydractl binary: install the package, or pass --hydractl PATH")
    return found


def reference_for(model: str, machine_id: str) -> Path:
    """The machine's reference model: `--model` itself when a file; in a
    folder, `MACHINE_ID.toml`, else `default.toml`."""
    p = Path(model)
    if p.is_dir():
        own = p / f"{machine_id}.toml"
        return own if own.exists() else p / "default.toml"
    return p


def reference_params(path: Path) -> dict[str, float]:
    """The reference's parameters, named as `model diagnose` names them
    (`inertia`, `coulomb_friction.coulomb`)."""
    with path.open("rb") as f:
        model = tomllib.load(f)
    params = {k: float(v) for k, v in model.get("plant", {}).items() if isinstance(v, (int, float))}
    for effect, keys in model.get("effects", {}).items():
        params.update({f"{effect}.{k}": float(v) for k, v in keys.items() if isinstance(v, (int, float))})
    return params


def empty_row(task: Task, error: str | None = None) -> dict:
    """A task's row before anything is known of it (see `results.SCHEMA`)."""
    rec = task.recording
    return {
        "machine_id": rec.machine_id,
        "recording": rec.path,
        "size": rec.size,
        "window_from_s": task.window_from_s,
        "window_to_s": task.window_to_s,
        "start": rec.start + dt.timedelta(seconds=task.window_from_s or 0.0),
        "start_from": rec.start_from,
        "duration_s": rec.duration_s,
        "reference": None,
        "reference_params": None,
        "nrmse": None,
        "baseline_params": None,
        "baseline_std": None,
        "baseline_inseparable": None,
        "effects": [],
        "verdict": None,
        "warnings": [],
        "error": error,
        "cpu_s": None,
        "max_rss_mb": None,
        "host": None,
    }


def diagnose(task: Task, model: str, hydractl: str, threads: int | None = None) -> dict:
    """The row of one task; with `threads`, hydractl's fits use that many
    (a Ray task its share of CPUs, not every core of the node)."""
    rec = task.recording
    row = empty_row(task)
    row["host"] = os.uname().nodename
    try:
        reference = reference_for(model, rec.machine_id)
        row["reference"] = str(reference)
        row["reference_params"] = reference_params(reference)
    except (OSError, ValueError, tomllib.TOMLDecodeError) as e:
        row["error"] = f"reference model for {rec.machine_id}: {e}"
        return row
    command = [hydractl, "model", "diagnose", "--data", rec.path, "--model", str(reference), "--json"]
    if task.window_from_s is not None:
        command += ["--from", repr(task.window_from_s), "--to", repr(task.window_to_s)]
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads)) if threads else None
    code, out, err, usage = _run(command, env)
    row["cpu_s"] = usage[0]
    row["max_rss_mb"] = usage[1]
    if code != 0:
        row["error"] = _last_error(err) or f"hydractl exited with {code}"
        return row
    try:
        report = json.loads(out)
    except json.JSONDecodeError as e:
        row["error"] = f"hydractl's answer is not JSON: {e}"
        return row
    base = report["baseline"]
    row["nrmse"] = {k: float(v) for k, v in base["validation_nrmse_by_output"].items()}
    row["nrmse"]["overall"] = float(base["validation_nrmse"])
    row["baseline_params"] = {k: float(v) for k, v in base.get("params", {}).items()}
    row["baseline_std"] = {k: float(v) for k, v in base["uncertainty"]["std"].items()}
    row["baseline_inseparable"] = sorted({p for pair in base["uncertainty"]["inseparable_pairs"] for p in pair["parameters"]})
    row["effects"] = [
        {
            "effect": c["effect"],
            "output": c["output"],
            "nrmse_before": float(c["validation_nrmse_before"]),
            "nrmse_after": float(c["validation_nrmse_after"]),
            "params": {k: float(v) for k, v in c["params"].items()},
            "test": c["test"],
            "statistic": float(c["statistic"]),
            "threshold": float(c["threshold"]),
        }
        for c in report["candidates"]
        if c["significant"]
    ]
    row["verdict"] = report["verdict"]
    row["warnings"] = _warnings(err)
    if task.window_from_s is not None and rec.duration_s is not None:
        row["duration_s"] = min(task.window_to_s, rec.duration_s) - task.window_from_s
    return row


def _run(command: list[str], env: dict | None) -> tuple[int, str, str, tuple[float, float]]:
    """Exit code, stdout, stderr and the child's own CPU seconds and peak
    memory (MB), through wait4: the figures a fleet's cost is made of."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        started = time.monotonic()
        child = subprocess.Popen(command, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env)
        timer = threading.Timer(TIMEOUT_S, child.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(child.pid, 0)
        finally:
            timer.cancel()
        child.returncode = os.waitstatus_to_exitcode(status)
        if time.monotonic() - started >= TIMEOUT_S:
            return 124, "", f"Error: no answer after {TIMEOUT_S:.0f} s (killed)", (usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024)
        out.seek(0)
        err.seek(0)
        return (
            child.returncode,
            out.read().decode(errors="replace"),
            err.read().decode(errors="replace"),
            (usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024),
        )


def _warnings(stderr: str) -> list[str]:
    """What hydractl warned of while reading (a file cut short, readings
    without a sensor's value): the row keeps it beside the diagnosis."""
    return [line.split("}: ", 1)[-1].strip() for line in stderr.splitlines() if " WARN " in line or line.startswith("WARN")]


def _last_error(stderr: str) -> str | None:
    """hydractl's `Error: …` line (anyhow's chain follows it), whole."""
    lines = stderr.strip().splitlines()
    for i, line in enumerate(lines):
        if line.startswith("Error:"):
            return " ".join(s.strip() for s in lines[i:] if s.strip())[:2000]
    return lines[-1][:2000] if lines else None
