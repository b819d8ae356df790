"""`hydractl-fleet diagnose`: one Ray task per recording (or window), the
rows written as they come back."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from tqdm import tqdm

from . import results, sources, tasks

# Rows are written in batches so that a run stopped halfway keeps its work.
BATCH = 32


def plan(paths: list[str], window_s: float | None, results_dir: Path) -> tuple[list[sources.Task], int]:
    """The tasks not yet in the results, and how many were skipped."""
    seen = results.done(results_dir)
    todo, skipped = [], 0
    for path in sources.find(paths):
        for task in sources.tasks(sources.describe(path), window_s):
            if task.key in seen:
                skipped += 1
            else:
                todo.append(task)
    return todo, skipped


def run(
    paths: list[str],
    model: str,
    results_dir: Path,
    *,
    address: str | None,
    cpus: int | None,
    window_s: float | None,
    hydractl: str | None,
    serial: bool = False,
) -> dict:
    """Diagnoses what is new under `paths`; returns the run's figures."""
    binary = tasks.hydractl_binary(hydractl)
    if not Path(model).exists():
        raise FileNotFoundError(f"--model {model}: no such file or folder")
    todo, skipped = plan(paths, window_s, results_dir)
    started = time.monotonic()
    bar = tqdm(total=len(todo), unit="task", desc="diagnose", file=sys.stderr, disable=None)
    pending_rows: list[dict] = []
    summary = {"tasks": len(todo), "skipped": skipped, "failed": 0, "files": []}

    def take(row: dict) -> None:
        pending_rows.append(row)
        summary["failed"] += row["error"] is not None
        bar.update(1)
        if len(pending_rows) >= BATCH:
            summary["files"].append(str(results.write(results_dir, pending_rows)))
            pending_rows.clear()

    try:
        if serial:
            for task in todo:
                take(tasks.diagnose(task, model, binary))
        elif todo:
            _on_ray(todo, model, binary, address, cpus, take)
    finally:
        written = results.write(results_dir, pending_rows)
        if written:
            summary["files"].append(str(written))
        bar.close()
    summary["wall_s"] = time.monotonic() - started
    return summary


def _on_ray(todo, model, binary, address, cpus, take) -> None:
    import ray

    ray.init(
        address=address,
        num_cpus=cpus if address is None else None,
        include_dashboard=False,
        log_to_driver=False,
        configure_logging=False,
    )
    try:
        # One CPU each, and hydractl's fits on that one: Ray fills the
        # node's CPUs with tasks, not one task with threads.
        remote = ray.remote(num_cpus=1, max_retries=1)(tasks.diagnose)
        waiting = {remote.remote(task, model, binary, 1): task for task in todo}
        while waiting:
            ready, _ = ray.wait(list(waiting), num_returns=1)
            for ref in ready:
                task = waiting.pop(ref)
                try:
                    take(ray.get(ref))
                except Exception as e:  # a worker lost with its task: a row, not a lost night
                    take(_lost(task, e))
    finally:
        ray.shutdown()


def _lost(task: sources.Task, error: Exception) -> dict:
    first = str(error).splitlines()[0] if str(error) else ""
    return tasks.empty_row(task, f"the task was lost: {type(error).__name__}: {first}")
