"""The fleet end to end, as a reliability engineer would run it: three
machines with plants of their own, five to eight days each, one of them
recorded by the whole stack on the virtual CAN bus as the vehicle records;
one whose Coulomb friction grows day by day, one whose valve dead band widens, one
steady; a truncated recording and a CSV without its angle among them.
Diagnosed on a local Ray, the trend must name the two drifting machines
with the right effect and direction, within two days of where a person
reading the parameters would see it, and nothing on the steady one; a
second run must skip everything done.

Needs `HYDRACTL` (the binary) and, for the CAN runs, the run scope the
caller set (`HYDRACTL_IPC_PREFIX`, `HYDRACTL_STATE_DIR`)."""

from __future__ import annotations

import concurrent.futures
import datetime as dt
import json
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
import unittest
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
HYDRACTL = os.environ.get("HYDRACTL", str(REPO / "target/release/hydractl"))
FLEET = [str(Path(sys.executable).parent / "hydractl-fleet")]
DAYS = 8
# The CAN machine drives in real time: fewer days keep this test short.
CAN_DAYS = 5
FIRST = dt.date(2026, 11, 3)
SHARE = 0.2
SIM_S = "30"
CAN_S = "12"


def day_name(d: int) -> str:
    return (FIRST + dt.timedelta(days=d)).isoformat()


# The CPUs the loop leaves free: every CPU this test may use but the one
# the configs pin the loop to (`[timing] loop_cpu` of config/sim.toml,
# which can.toml and machine.toml take as their base).
LOOP_CPU = tomllib.loads((REPO / "config" / "sim.toml").read_text())["timing"].get("loop_cpu")
FREE_CPUS = sorted(os.sched_getaffinity(0) - {LOOP_CPU}) or sorted(os.sched_getaffinity(0))
# Through exec (a `preexec_fn` is unsafe beside the thread that drives the
# CAN machine). At nice 5: below the stack's own processes there, above the
# other tests that only compute (nice 19), which would otherwise starve
# this work past the CAN machine's days and make the test wait for it.
BESIDE_THE_LOOP = [sys.executable, "-c", "import os, sys; os.sched_setaffinity(0, {int(c) for c in sys.argv[1].split(',')}); "
                   "os.nice(5); os.execvp(sys.argv[2], sys.argv[2:])", ",".join(map(str, FREE_CPUS))]


def run(argv: list[str], beside: bool) -> subprocess.CompletedProcess:
    done = subprocess.run((BESIDE_THE_LOOP if beside else []) + argv, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise AssertionError(f"{' '.join(argv)}: {done.stderr[-3000:]}")
    return done


def hydractl(*args: str, beside: bool = False) -> None:
    run([HYDRACTL, *args], beside)


def fleet(*args: str, beside: bool = False) -> subprocess.CompletedProcess:
    return run(FLEET + list(args), beside)


# rotator-a, on CAN: Coulomb friction 30 N·m on the first day, 3 more a day.
def coulomb(d: int) -> float:
    return 30.0 + 3.0 * d


# rotator-b: the valve's dead band, 0.04 of the command, 0.006 wider a day.
def dead_band(d: int) -> float:
    return 0.04 + 0.006 * d


def make_simulated_machines(root: Path) -> dict:
    """rotator-b and rotator-c: eight days each, each machine's reference the
    model `model learn` made of its first day, diagnosed one after another
    beside the loop (Ray runs its workers at nice 15, among the tests that
    only compute, which would starve them; the CAN days are diagnosed on
    Ray). Returns the diagnosis's summary."""
    data, refs = root / "fleet", root / "refs"
    plants = {
        "b": "[plant]\ninertia = 17.0\nflow_gain = 4.4e-5\n",
        "c": "[plant]\ninertia = 21.0\nviscous_friction = 15.0\n",
    }
    for m, plant in plants.items():
        (root / f"{m}.toml").write_text(f'base = "{REPO}/config/sim.toml"\n{plant}')
    for d in range(DAYS):
        hydractl("sim", "--config", str(root / "b.toml"), "--duration", SIM_S, "--seed", str(200 + d),
                 "--effect", f"deadzone:width={dead_band(d)}",
                 "--out", str(data / "rotator-b" / f"{day_name(d)}.csv"), beside=True)
        hydractl("sim", "--config", str(root / "c.toml"), "--duration", SIM_S, "--seed", str(300 + d),
                 "--effect", "coulomb_friction:coulomb=30,breakaway=42",
                 "--out", str(data / "rotator-c" / f"{day_name(d)}.csv"), beside=True)
    for machine in ("rotator-b", "rotator-c"):
        hydractl("model", "learn", "--data", str(data / machine / f"{day_name(0)}.csv"),
                 "--out", str(refs / f"{machine}.toml"), beside=True)
    return json.loads(
        fleet("diagnose", str(data / "rotator-b"), str(data / "rotator-c"), "--model", str(refs),
              "--out", str(root / "results"), "--serial", "--hydractl", HYDRACTL, "--json", beside=True).stdout
    )


def make_fleet(root: Path) -> dict:
    """The whole fleet; the simulated machines made and diagnosed while the
    CAN machine drives (a night's run meeting a vehicle still out), which
    keeps this test short. Returns that first diagnosis's summary."""
    data, refs = root / "fleet", root / "refs"
    for folder in ("can-dump", "rotator-b", "rotator-c"):
        (data / folder).mkdir(parents=True)
    refs.mkdir()
    with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
        simulated = pool.submit(make_simulated_machines, root)
        for d in range(CAN_DAYS):
            # The CAN machine names itself in its recordings' metadata; its
            # files sit in a folder that is not its name.
            (root / f"a{d}.toml").write_text(
                f'base = "{REPO}/config/can.toml"\n[machine]\nid = "rotator-a"\nseed = {10 + d}\n'
                f"[machine.plant]\ninertia = 24.0\nviscous_friction = 22.0\n"
                f"[machine.effects.coulomb_friction]\ncoulomb = {coulomb(d)}\nbreakaway = {1.4 * coulomb(d)}\n"
            )
            hydractl("run", "--config", str(root / f"a{d}.toml"), "--duration", CAN_S,
                     "--record", str(data / "can-dump" / f"{day_name(d)}.mcap"))
        early = simulated.result()
    hydractl("model", "learn", "--data", str(data / "can-dump" / f"{day_name(0)}.mcap"),
             "--out", str(refs / "rotator-a.toml"))
    # What a night's copy brings too: a recording cut short, a CSV without its angle.
    whole = (data / "can-dump" / f"{day_name(0)}.mcap").read_bytes()
    (data / "rotator-c" / "2026-11-11.mcap").write_bytes(whole[:6000])
    lines = (data / "rotator-b" / f"{day_name(0)}.csv").read_text().splitlines()
    header = lines[0].split(",")
    theta = header.index("theta")
    (data / "rotator-b" / "2026-11-11.csv").write_text(
        "\n".join(",".join(f for i, f in enumerate(line.split(",")) if i != theta) for line in lines) + "\n"
    )
    return early


def trend(results: Path, until: str | None = None) -> dict:
    args = ["trend", str(results), "--json", "--share", str(SHARE)] + (["--until", until] if until else [])
    return {m["machine_id"]: m for m in json.loads(fleet(*args).stdout)["machines"]}


class Fleet(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.root = Path(tempfile.mkdtemp(prefix="hydractl-fleet-"))
        cls.early = make_fleet(cls.root)
        cls.results = cls.root / "results"
        cls.first = json.loads(
            fleet("diagnose", str(cls.root / "fleet"), "--model", str(cls.root / "refs"),
                  "--out", str(cls.results), "--cpus", "2", "--hydractl", HYDRACTL, "--json").stdout
        )
        cls.machines = trend(cls.results)

    @classmethod
    def tearDownClass(cls):
        if not os.environ.get("HYDRACTL_KEEP_SCRATCH"):
            shutil.rmtree(cls.root, ignore_errors=True)

    def drifts(self, machine: str) -> list[dict]:
        return self.machines[machine]["drifting"]

    def test_every_recording_is_a_row_and_a_night_does_only_the_new_ones(self):
        self.assertEqual((self.early["tasks"], self.early["failed"]), (2 * DAYS, 0), self.early)
        self.assertEqual((self.first["tasks"], self.first["skipped"]), (CAN_DAYS + 2, 2 * DAYS), self.first)
        self.assertEqual(self.first["failed"], 2, self.first)
        self.assertEqual(sorted(self.machines), ["rotator-a", "rotator-b", "rotator-c"])
        self.assertEqual(self.machines["rotator-a"]["recordings"], CAN_DAYS)

    def test_growing_friction_is_named_rising(self):
        named = [d for d in self.drifts("rotator-a") if d.get("effect") == "coulomb_friction"]
        self.assertIn("coulomb_friction.coulomb", [d["parameter"] for d in named], named)
        self.assertTrue(all(d["direction"] == "rising" and d["slope"] > 0 for d in named), named)
        self.assertEqual({d.get("effect") for d in self.drifts("rotator-a")}, {"coulomb_friction"}, self.drifts("rotator-a"))

    def test_widening_dead_band_is_named_rising(self):
        named = [d for d in self.drifts("rotator-b") if d.get("effect") == "deadzone"]
        self.assertTrue(named, self.drifts("rotator-b"))
        self.assertTrue(all(d["direction"] in ("rising", "new") for d in named), named)
        self.assertEqual({d.get("effect") for d in self.drifts("rotator-b")}, {"deadzone"}, self.drifts("rotator-b"))

    def test_the_steady_machine_raises_nothing(self):
        self.assertEqual(self.drifts("rotator-c"), [])
        self.assertNotEqual(self.machines["rotator-c"]["state"], "drifting")

    def test_seen_within_two_days_of_a_person_reading_the_parameters(self):
        """A person sees a drift on the first day from which the fitted
        value stays more than the share from the reference (one failed fit
        aside); the trend must name it no later than two days after."""
        for machine, effect, parameter in (("rotator-a", "coulomb_friction", "coulomb_friction.coulomb"), ("rotator-b", "deadzone", "deadzone.width")):
            series = self.series(machine, parameter)
            reference = series[0][2]
            away = [abs(v - reference) > SHARE * abs(reference) for _, v, _ in series]
            person = next(d for d in range(len(series)) if away[d] and away[d:].count(False) <= 1)
            named = next(
                (d for d in range(len(series)) if any(x.get("effect") == effect for x in trend(self.results, day_name(d))[machine]["drifting"])),
                None,
            )
            self.assertIsNotNone(named, f"{machine}: never named")
            self.assertLessEqual(named, person + 2, f"{machine}: a person sees it on day {person}, the trend names it on day {named}")

    def series(self, machine: str, parameter: str) -> list[tuple[str, float, float]]:
        sys.path.insert(0, str(REPO / "tools/fleet"))
        from hydractl_fleet import results

        rows = sorted((r for r in results.read(self.results) if r["machine_id"] == machine and r["error"] is None), key=lambda r: r["start"])
        return [(r["start"], r["baseline_params"][parameter], r["reference_params"][parameter]) for r in rows]

    def test_bad_recordings_are_rows_with_their_error(self):
        failures = {Path(f["recording"]).name: f["error"] for m in self.machines.values() for f in m["failures"]}
        self.assertEqual(sorted(failures), ["2026-11-11.csv", "2026-11-11.mcap"], failures)
        self.assertIn("theta", failures["2026-11-11.csv"])
        self.assertIn("2026-11-11.mcap", failures["2026-11-11.mcap"])

    def test_a_second_run_skips_everything_done(self):
        again = json.loads(
            fleet("diagnose", str(self.root / "fleet"), "--model", str(self.root / "refs"),
                  "--out", str(self.results), "--serial", "--hydractl", HYDRACTL, "--json").stdout
        )
        self.assertEqual((again["tasks"], again["skipped"]), (0, 2 * DAYS + CAN_DAYS + 2), again)

    def test_a_long_recording_is_diagnosed_window_by_window(self):
        """Each window read through the recording's index: a row each, at
        its own start and of its own length, the reference fitting it."""
        windows = self.root / "windows"
        day = self.root / "fleet" / "can-dump" / f"{day_name(CAN_DAYS - 1)}.mcap"
        run = json.loads(
            fleet("diagnose", str(day), "--model", str(self.root / "refs"), "--out", str(windows),
                  "--window", "6", "--serial", "--hydractl", HYDRACTL, "--json").stdout
        )
        sys.path.insert(0, str(REPO / "tools/fleet"))
        from hydractl_fleet import results

        rows = sorted(results.read(windows), key=lambda r: r["window_from_s"])
        errors = [(r["window_from_s"], r["error"]) for r in rows if r["error"] is not None]
        self.assertEqual((run["tasks"], run["failed"]), (2, 0), (run, errors))
        self.assertEqual([r["window_from_s"] for r in rows], [0.0, 6.0])
        self.assertEqual((rows[1]["start"] - rows[0]["start"]).total_seconds(), 6.0)
        # The last window takes the remainder shorter than half a window.
        self.assertAlmostEqual(rows[0]["duration_s"], 6.0, delta=0.01)
        self.assertTrue(6.0 <= rows[1]["duration_s"] < 9.0, rows[1]["duration_s"])
        for row in rows:
            self.assertLess(row["nrmse"]["theta"], 0.05, row)

    def test_the_report_shows_every_machine_and_its_drift(self):
        out = self.root / "fleet.html"
        fleet("report", str(self.results), "--out", str(out))
        page = out.read_text()
        for machine in ("rotator-a", "rotator-b", "rotator-c"):
            self.assertIn(machine, page)
        self.assertIn("coulomb_friction.coulomb — drifting", page)
        self.assertNotIn("<script", page)


if __name__ == "__main__":
    unittest.main(verbosity=2)
