#!/usr/bin/env python3
"""Holds the counts that do not move with a machine's load to their baselines.

    guard.py BASELINES INSTRUCTIONS SYSCALLS [--update]

BASELINES is tools/benches/baselines.json; INSTRUCTIONS the JSON lines of
`cargo bench -p hydractl-benches --bench instructions -- --output-format=json`;
SYSCALLS the JSON of `hydractl bench syscalls --json`. A count more than
`limit_percent` over its baseline fails, naming the benchmark and both
counts; a count that fell as much is said, so that a baseline can be
lowered to hold the gain. `--update` writes the counts as the new
baselines: a commit of its own, whose message says why.
"""

import json
import sys


def instructions(path):
    counts = {}
    with open(path) as lines:
        for line in lines:
            line = line.strip()
            if not line:
                continue
            bench = json.loads(line)
            for profile in bench["profiles"]:
                if profile["tool"] != "Callgrind":
                    continue
                counts[bench["function_name"]] = profile["data"]["total"]["metrics"]["Ir"]["values"]["new"]
    return counts


def syscalls(path):
    with open(path) as text:
        report = json.load(text)
    return {stage["stage"]: stage["per_cycle"] for stage in report["stages"]}


def main(argv):
    update = "--update" in argv
    args = [a for a in argv if a != "--update"]
    if len(args) != 3:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    baselines_path, instructions_path, syscalls_path = args
    with open(baselines_path) as text:
        baselines = json.load(text)
    measured = {
        "instructions": instructions(instructions_path),
        "syscalls_per_cycle": syscalls(syscalls_path),
    }
    if update:
        for kind, counts in measured.items():
            baselines[kind] = {
                name: (round(count, 2) if isinstance(count, float) else count) for name, count in sorted(counts.items())
            }
        with open(baselines_path, "w") as text:
            json.dump(baselines, text, indent=2)
            text.write("\n")
        print(f"wrote the counts as the baselines in {baselines_path}")
        return 0

    limit = baselines["limit_percent"]
    failures = []
    print(f"{'count':<34} {'baseline':>14} {'now':>14} {'change':>8}")
    for kind, unit in (("instructions", "instructions"), ("syscalls_per_cycle", "system calls per reading")):
        for name, baseline in baselines[kind].items():
            label = f"{kind}/{name}"
            now = measured[kind].get(name)
            if now is None:
                failures.append(f"{label}: no count was measured (the benchmark is gone or failed)")
                print(f"{label:<34} {baseline:>14} {'-':>14}")
                continue
            change = 100.0 * (now - baseline) / baseline
            shown = f"{now:>14}" if isinstance(now, int) else f"{now:>14.3f}"
            print(f"{label:<34} {baseline:>14} {shown} {change:>+7.1f}%")
            if change > limit:
                failures.append(
                    f"{label} grew {change:.1f} % over its baseline (limit {limit} %): "
                    f"{now} {unit} against {baseline}"
                )
            elif change < -limit:
                print(f"  {label} fell {-change:.1f} %: lower its baseline to hold the gain (--update, in a commit of its own)")
        for name in sorted(set(measured[kind]) - set(baselines[kind])):
            print(f"  {kind}/{name} has no baseline yet: add one (--update, in a commit of its own)")
    if failures:
        print("\nThe count guard failed:", file=sys.stderr)
        for failure in failures:
            print(f"  {failure}", file=sys.stderr)
        print(
            f"A baseline ({baselines_path}) is raised only by a commit of its own that says why.",
            file=sys.stderr,
        )
        return 1
    print(f"\nevery count within {limit} % of its baseline")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
