"""The `hydractl-fleet` command line: diagnose, trend, report."""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path

from . import diagnose, report, results, trend


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="hydractl-fleet", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    d = commands.add_parser("diagnose", help="diagnose every new recording, one Ray task each")
    d.add_argument("paths", nargs="+", metavar="PATH", help="recordings (.mcap, .csv) or folders of them")
    d.add_argument("--model", required=True, help="the reference model; or a folder of MACHINE_ID.toml and default.toml")
    d.add_argument("--out", required=True, type=Path, help="the results folder (Parquet)")
    d.add_argument("--address", default=None, help="a running Ray cluster (`auto`, or ray://HOST:10001) [default: a local Ray]")
    d.add_argument("--cpus", type=int, default=None, help="CPUs of the local Ray [default: all]")
    d.add_argument("--window", type=float, default=None, metavar="SECONDS", help="one task per window of a long recording")
    d.add_argument("--hydractl", default=None, help="the hydractl binary [default: $HYDRACTL, else on the PATH]")
    d.add_argument("--serial", action="store_true", help="one after another in this process, without Ray")
    d.add_argument("--json", action="store_true", help="the run's figures as JSON")

    t = commands.add_parser("trend", help="per machine, the parameters' trends and what drifts")
    t.add_argument("results", type=Path, metavar="RESULTS_DIR")
    t.add_argument("--share", type=float, default=0.2, help="a trend this far from the reference value drifts [default: 0.2]")
    t.add_argument("--until", type=_date, default=None, metavar="DATE", help="the fleet as it stood then: its recordings up to this ISO date or date-time")
    t.add_argument("--json", action="store_true")

    r = commands.add_parser("report", help="the fleet at a glance, and each machine's parameters over time, as one HTML page")
    r.add_argument("results", type=Path, metavar="RESULTS_DIR")
    r.add_argument("--out", required=True, type=Path)
    r.add_argument("--share", type=float, default=0.2)

    args = parser.parse_args(argv)
    try:
        return {"diagnose": _diagnose, "trend": _trend, "report": _report}[args.command](args)
    except (FileNotFoundError, ValueError) as e:
        print(f"Error: {e}", file=sys.stderr)
        return 1


def _diagnose(args) -> int:
    if args.window is not None and args.window <= 0:
        raise ValueError(f"--window {args.window}: must be positive")
    summary = diagnose.run(
        args.paths,
        args.model,
        args.out,
        address=args.address,
        cpus=args.cpus,
        window_s=args.window,
        hydractl=args.hydractl,
        serial=args.serial,
    )
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{summary['tasks']} task(s) diagnosed in {summary['wall_s']:.1f} s, {summary['failed']} with an error, "
            f"{summary['skipped']} already in {args.out}"
        )
    return 0


def _date(text: str) -> dt.datetime:
    t = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    # A date alone means the whole of that day.
    return t + dt.timedelta(days=1) - dt.timedelta(microseconds=1) if len(text) == 10 else t


def _checked(results_dir: Path) -> list[dict]:
    rows = results.read(results_dir)
    if not rows:
        raise FileNotFoundError(f"{results_dir}: no results (run `hydractl-fleet diagnose ... --out {results_dir}`)")
    return rows


def _trend(args) -> int:
    fleet = trend.analyse(_checked(args.results), args.share, args.until)
    if args.json:
        out = {"share": fleet["share"], "machines": [{k: v for k, v in m.items() if k != "series"} for m in fleet["machines"]]}
        print(json.dumps(out, indent=2))
        return 0
    for m in fleet["machines"]:
        print(f"{m['machine_id']}: {m['state']}, {m['recordings']} recording(s), last seen {m['last_seen']}, {m['errors']} error(s)")
        for d in m["drifting"]:
            print(f"  {d.get('effect') or d['parameter']} {d['direction']}: {d['evidence']}")
        for f in m["failures"]:
            print(f"  error in {f['recording']}: {f['error']}")
    return 0


def _report(args) -> int:
    fleet = trend.analyse(_checked(args.results), args.share)
    report.write(fleet, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
