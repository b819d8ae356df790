"""The trend's rules on made-up rows: a drift past the share is named, a
steady scatter is not, a failed fit does not bend the line, an offset is
never judged by its share, a parameter the data fixes only in a
combination is not named, a new effect needs the last recordings."""

from __future__ import annotations

import datetime as dt
import sys
import unittest
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hydractl_fleet import trend  # noqa: E402

DAY0 = dt.datetime(2026, 11, 3, tzinfo=dt.timezone.utc)


def row(day: int, params: dict, effects: tuple = (), error: str | None = None) -> dict:
    return {
        "machine_id": "m",
        "recording": f"/fleet/m/{day}.csv",
        "window_from_s": None,
        "start": DAY0 + dt.timedelta(days=day),
        "reference_params": {"coulomb_friction.coulomb": 30.0, "deadzone.offset": 0.001},
        "baseline_params": None if error else params,
        "nrmse": None if error else {"overall": 0.02},
        "effects": [
            {"effect": e, "output": "theta", "nrmse_before": 0.04, "nrmse_after": 0.01, "params": {"width": 0.05},
             "test": "paired_t", "statistic": 9.0, "threshold": 3.6}
            for e in effects
        ],
        "error": error,
    }


def drifts(rows: list[dict]) -> list[dict]:
    return trend.analyse(rows)["machines"][0]["drifting"]


class Trend(unittest.TestCase):
    def test_a_parameter_past_the_share_is_named_with_its_direction(self):
        rows = [row(d, {"coulomb_friction.coulomb": 30.0 + 3.0 * d + 0.2 * (-1) ** d}) for d in range(8)]
        [named] = drifts(rows)
        self.assertEqual((named["effect"], named["direction"]), ("coulomb_friction", "rising"))
        self.assertAlmostEqual(named["slope"], 3.0, delta=0.1)

    def test_a_parameter_the_data_fixes_only_in_a_combination_is_shown_not_named(self):
        rows = [row(d, {"coulomb_friction.coulomb": 30.0, "coulomb_friction.stribeck_velocity": 0.05 - 0.003 * d}) for d in range(8)]
        for r in rows:
            r["reference_params"]["coulomb_friction.stribeck_velocity"] = 0.05
        self.assertEqual(len(drifts(rows)), 1)
        for r in rows[2:]:
            r["baseline_inseparable"] = ["coulomb_friction.breakaway", "coulomb_friction.stribeck_velocity"]
        machine = trend.analyse(rows)["machines"][0]
        self.assertEqual(machine["drifting"], [])
        self.assertEqual(machine["inseparable"], ["coulomb_friction.stribeck_velocity"])

    def test_a_steady_scatter_is_not(self):
        rows = [row(d, {"coulomb_friction.coulomb": 30.0 + 2.0 * (-1) ** d}) for d in range(8)]
        self.assertEqual(drifts(rows), [])

    def test_a_significant_trend_within_the_share_is_not(self):
        rows = [row(d, {"coulomb_friction.coulomb": 30.0 + 0.5 * d}) for d in range(8)]
        self.assertEqual(drifts(rows), [])

    def test_a_failed_fit_is_left_out_of_the_line(self):
        values = [30.0 + 3.0 * d for d in range(8)]
        values[5] = 5.0  # two inseparable parameters traded places
        line = trend.fit_line(list(range(8)), values)
        self.assertEqual(line.left_out, 1)
        self.assertAlmostEqual(line.slope, 3.0, delta=1e-9)

    def test_a_recording_left_out_costs_the_trend_a_degree_of_freedom(self):
        # A steady parameter the fits scatter: with the far one left out,
        # the four others lie near a falling line (t = 5.4, past 4.3 for
        # two degrees of freedom), 27 % under the reference by its end.
        values = [0.050, 0.047, 0.010, 0.045, 0.041]
        rows = [row(d, {"coulomb_friction.stribeck_velocity": v}) for d, v in enumerate(values)]
        for r in rows:
            r["reference_params"]["coulomb_friction.stribeck_velocity"] = 0.056
        line = trend.fit_line(list(range(5)), values)
        self.assertEqual((line.left_out, line.dof), (1, 1))
        self.assertEqual(drifts(rows), [])

    def test_an_offset_is_not_judged_by_its_share(self):
        rows = [row(d, {"deadzone.offset": 0.001 + 0.001 * d}) for d in range(8)]
        self.assertEqual(drifts(rows), [])

    def test_an_effect_the_reference_lacks_is_new_once_the_last_recordings_all_have_it(self):
        steady = {"coulomb_friction.coulomb": 30.0}
        rows = [row(d, steady, ("backlash",) if d in (3, 5, 6, 7) else ()) for d in range(8)]
        [named] = drifts(rows)
        self.assertEqual((named["effect"], named["direction"]), ("backlash", "new"))
        rows[6]["effects"] = []
        self.assertEqual(drifts(rows), [])

    def test_a_machine_whose_newest_recording_failed_is_unreadable(self):
        rows = [row(d, {"coulomb_friction.coulomb": 30.0}) for d in range(4)] + [row(4, {}, error="cut short")]
        machine = trend.analyse(rows)["machines"][0]
        self.assertEqual((machine["state"], machine["errors"]), ("unreadable", 1))

    def test_until_shows_the_fleet_as_it_stood(self):
        rows = [row(d, {"coulomb_friction.coulomb": 30.0 + 3.0 * d}) for d in range(8)]
        self.assertEqual(trend.analyse(rows, until=DAY0 + dt.timedelta(days=1))["machines"][0]["drifting"], [])


if __name__ == "__main__":
    unittest.main()
