"""The fleet's scale on this computer: the same recordings diagnosed on a
local Ray and one after another, in recordings per minute, with the memory
of a Ray worker and of a diagnosis, and the CPU-seconds one machine-hour
of data costs.

    python tools/fleet/bench_scale.py [--machines 3] [--days 8] [--seconds 60] [--cpus 2]

Needs `hydractl` (`HYDRACTL`, else target/release/hydractl) and the
package installed (`pip install ./tools/fleet`)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
HYDRACTL = os.environ.get("HYDRACTL", str(REPO / "target/release/hydractl"))
FLEET = str(Path(sys.executable).parent / "hydractl-fleet")


def make(root: Path, machines: int, days: int, seconds: int) -> None:
    for m in range(machines):
        folder = root / "fleet" / f"machine-{m}"
        folder.mkdir(parents=True)
        for d in range(days):
            coulomb = 20 + 3 * d * (m == 0)
            subprocess.run([HYDRACTL, "sim", "--duration", str(seconds), "--seed", str(100 * m + d),
                            "--effect", f"coulomb_friction:coulomb={coulomb},breakaway={1.4 * coulomb}",
                            "--out", str(folder / f"2026-11-{3 + d:02d}.csv")], check=True, capture_output=True)
    (root / "refs").mkdir()
    for m in range(machines):
        subprocess.run([HYDRACTL, "model", "learn", "--data", str(root / "fleet" / f"machine-{m}" / "2026-11-03.csv"),
                        "--out", str(root / "refs" / f"machine-{m}.toml")], check=True, capture_output=True)


def ray_worker_rss_mb(stop: threading.Event, peak: list[float]) -> None:
    """The largest resident memory of a Ray worker process, sampled."""
    while not stop.wait(0.2):
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
                if b"default_worker.py" not in cmdline:
                    continue
                for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                    if line.startswith("VmRSS:"):
                        peak[0] = max(peak[0], int(line.split()[1]) / 1024)
            except OSError:
                continue


def diagnose(root: Path, out: str, extra: list[str], env: dict | None = None) -> dict:
    started = time.monotonic()
    done = subprocess.run([FLEET, "diagnose", str(root / "fleet"), "--model", str(root / "refs"), "--out", str(root / out),
                           "--hydractl", HYDRACTL, "--json", *extra], check=True, capture_output=True, text=True, env=env)
    figures = json.loads(done.stdout)
    figures["wall_s"] = time.monotonic() - started
    return figures


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--machines", type=int, default=3)
    p.add_argument("--days", type=int, default=8)
    p.add_argument("--seconds", type=int, default=60)
    p.add_argument("--cpus", type=int, default=2)
    args = p.parse_args()
    sys.path.insert(0, str(Path(__file__).parent))
    from hydractl_fleet import results

    with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        root = Path(tmp)
        make(root, args.machines, args.days, args.seconds)
        n = args.machines * args.days
        stop, peak = threading.Event(), [0.0]
        sampler = threading.Thread(target=ray_worker_rss_mb, args=(stop, peak))
        sampler.start()
        on_ray = diagnose(root, "ray", ["--cpus", str(args.cpus)])
        stop.set()
        sampler.join()
        one_thread = diagnose(root, "serial-1", ["--serial"], dict(os.environ, RAYON_NUM_THREADS="1"))
        all_threads = diagnose(root, "serial", ["--serial"])
        rows = results.read(root / "ray")
        cpu = sum(r["cpu_s"] for r in rows)
        data_s = sum(r["duration_s"] for r in rows)
        rss = max(r["max_rss_mb"] for r in rows)
        per_minute = {k: 60 * n / f["wall_s"] for k, f in (("ray", on_ray), ("serial_one_thread", one_thread), ("serial", all_threads))}
        print(json.dumps({
            "recordings": n,
            "seconds_each": args.seconds,
            "cpus": args.cpus,
            "recordings_per_minute": per_minute,
            "ray_over_serial_one_thread": per_minute["ray"] / per_minute["serial_one_thread"],
            "ray_over_serial": per_minute["ray"] / per_minute["serial"],
            "cpu_s_per_machine_hour": 3600 * cpu / data_s,
            "diagnosis_max_rss_mb": rss,
            "ray_worker_max_rss_mb": peak[0],
            "parquet_bytes_per_row": sum(f.stat().st_size for f in (root / "ray").glob("*.parquet")) / len(rows),
        }, indent=2))


if __name__ == "__main__":
    main()
