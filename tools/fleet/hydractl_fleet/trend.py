"""`hydractl-fleet trend`: per machine and parameter, the trend over the
machine's life, and what drifts: a parameter whose trend has left its
reference by more than a stated share, an effect the reference lacks that
stays significant, a fit that degrades."""

from __future__ import annotations

import dataclasses
import datetime as dt
import math

# Two-sided 95 % quantiles of Student's t, by degrees of freedom (1-30);
# beyond, the normal's. A slope passing it is a direction the data shows;
# the share a trend must leave its reference by is what keeps a steady
# machine quiet, so the t need not be stricter and cost days.
_T975 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
         2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
         2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042]  # fmt: skip

# A trend needs this many recordings on this many days at least.
MIN_POINTS = 4
MIN_SPAN_DAYS = 1.0
# An effect the reference lacks is "new" once the last this many
# recordings all find it significant: one recording can be a fluke.
NEW_EFFECT_RUN = 3


def t_quantile(dof: int) -> float:
    return _T975[dof - 1] if 1 <= dof <= len(_T975) else 1.960


# A recording whose value lies this many robust deviations off the line
# through the others is a fit that failed (two inseparable parameters
# trading places), not the machine: it is left out of the trend.
OUTLIER_DEVIATIONS = 4.0


@dataclasses.dataclass
class Line:
    """A least-squares line through (day, value) with the slope's standard
    error, and the recordings left out as outliers."""

    intercept: float
    slope: float
    slope_stderr: float
    points: int
    span_days: float
    left_out: int = 0

    def at(self, day: float) -> float:
        return self.intercept + self.slope * day

    @property
    def t(self) -> float:
        if self.slope_stderr > 0:
            return abs(self.slope) / self.slope_stderr
        return math.inf if self.slope else 0.0

    @property
    def dof(self) -> int:
        """The t test's degrees of freedom. A recording left out for lying
        off the line was chosen by looking at the data, and the line
        through the rest fits them better than chance would: each costs
        one (without it, a steady parameter whose fits scatter, four left
        of five, passed for a trend)."""
        return self.points - 2 - self.left_out

    @property
    def significant(self) -> bool:
        return (
            self.points >= MIN_POINTS
            and self.span_days >= MIN_SPAN_DAYS
            and self.dof >= 1
            and self.t > t_quantile(self.dof)
        )


def fit_line(days: list[float], values: list[float]) -> Line | None:
    """Least squares, once the outliers are left out: those further than
    `OUTLIER_DEVIATIONS` robust deviations (1.4826 MAD) from the
    Theil-Sen line (the median of the pairwise slopes), at most a quarter."""
    pairs = [(values[j] - values[i]) / (days[j] - days[i]) for i in range(len(days)) for j in range(i + 1, len(days)) if days[j] != days[i]]
    if len(days) >= 5 and pairs:
        slope = _median(pairs)
        intercept = _median([v - slope * d for d, v in zip(days, values)])
        residuals = [v - intercept - slope * d for d, v in zip(days, values)]
        scale = 1.4826 * _median([abs(r) for r in residuals])
        # Nor is a sliver off a near-perfect line an outlier.
        limit = max(OUTLIER_DEVIATIONS * scale, 0.05 * abs(_median(values)))
        if limit > 0:
            far = sorted(range(len(days)), key=lambda i: -abs(residuals[i]))[: len(days) // 4]
            out = {i for i in far if abs(residuals[i]) > limit}
            if out:
                kept = [i for i in range(len(days)) if i not in out]
                line = _least_squares([days[i] for i in kept], [values[i] for i in kept])
                if line:
                    line.left_out = len(out)
                return line
    return _least_squares(days, values)


def _median(xs: list[float]) -> float:
    xs = sorted(xs)
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def _least_squares(days: list[float], values: list[float]) -> Line | None:
    n = len(days)
    if n < 2:
        return None
    mx, my = sum(days) / n, sum(values) / n
    sxx = sum((x - mx) ** 2 for x in days)
    if sxx == 0:
        return None
    slope = sum((x - mx) * (y - my) for x, y in zip(days, values)) / sxx
    intercept = my - slope * mx
    if n > 2:
        sse = sum((y - intercept - slope * x) ** 2 for x, y in zip(days, values))
        stderr = math.sqrt(sse / (n - 2) / sxx)
    else:
        stderr = math.inf
    return Line(intercept, slope, stderr, n, max(days) - min(days))


def analyse(rows: list[dict], share: float = 0.2, until: dt.datetime | None = None) -> dict:
    """The fleet's machines, each with its drifts (see the README's JSON);
    with `until`, as the fleet stood then (its recordings up to it)."""
    by_machine: dict[str, list[dict]] = {}
    for row in rows:
        if until is not None and row["start"] > until:
            continue
        by_machine.setdefault(row["machine_id"], []).append(row)
    machines = [_machine(mid, rs, share) for mid, rs in sorted(by_machine.items())]
    return {"share": share, "machines": machines}


def _days(rows: list[dict]) -> list[float]:
    first = rows[0]["start"]
    return [(r["start"] - first).total_seconds() / 86400.0 for r in rows]


def _machine(machine_id: str, rows: list[dict], share: float) -> dict:
    rows = sorted(rows, key=lambda r: (r["start"], r["window_from_s"] or 0.0))
    good = [r for r in rows if r["error"] is None]
    failed = [r for r in rows if r["error"] is not None]
    drifting: list[dict] = []
    series: dict[str, dict] = {}
    if good:
        days = _days(good)
        reference = good[-1]["reference_params"] or {}
        combined = _fixed_only_in_combination(good)
        for name in sorted({k for r in good for k in (r["baseline_params"] or {})}):
            points = [(d, r["baseline_params"][name]) for d, r in zip(days, good) if name in (r["baseline_params"] or {})]
            entry = _series(name, points, reference.get(name), share)
            if name in combined:
                entry["inseparable"] = True
            series[name] = entry
            if entry["drift"] and name not in combined:
                drifting.append(entry["drift"])
        drifting += _new_effects(good, days, reference)
        fit = _degrading_fit(good, days, share)
        if fit:
            drifting.append(fit)
    # Drifting: it needs a visit. Unreadable: its newest recording could
    # not be diagnosed, so its recorder or the copy needs a look.
    state = "drifting" if drifting else "steady" if good else "no data"
    if not drifting and rows and rows[-1]["error"] is not None:
        state = "unreadable"
    return {
        "machine_id": machine_id,
        "recordings": len({r["recording"] for r in rows}),
        "tasks": len(rows),
        "errors": len(failed),
        "first_seen": _iso(rows[0]["start"]) if rows else None,
        "last_seen": _iso(rows[-1]["start"]) if rows else None,
        "state": state,
        "drifting": drifting,
        "inseparable": sorted(n for n, e in series.items() if e.get("inseparable")),
        "series": series,
        "failures": [{"recording": r["recording"], "error": r["error"]} for r in failed],
    }


def _fixed_only_in_combination(good: list[dict]) -> set[str]:
    """The parameters the fits fixed only in a combination with another in
    most of the recordings that have them: a trend of one of them may be
    the other's moving (a Stribeck velocity falling as the breakaway
    torque rises), so it is shown and not named."""
    have: dict[str, int] = {}
    combined: dict[str, int] = {}
    for r in good:
        for name in r["baseline_params"] or {}:
            have[name] = have.get(name, 0) + 1
        for name in r.get("baseline_inseparable") or []:
            combined[name] = combined.get(name, 0) + 1
    return {name for name, n in combined.items() if 2 * n > have.get(name, 0)}


def _iso(t: dt.datetime) -> str:
    return t.astimezone(dt.timezone.utc).isoformat().replace("+00:00", "Z")


def _series(name: str, points: list[tuple[float, float]], reference: float | None, share: float) -> dict:
    days, values = [p[0] for p in points], [p[1] for p in points]
    line = fit_line(days, values)
    entry = {
        "days": days,
        "values": values,
        "reference": reference,
        "slope": line.slope if line else None,
        "slope_stderr": line.slope_stderr if line and math.isfinite(line.slope_stderr) else None,
        "intercept": line.intercept if line else None,
        "drift": None,
    }
    # An offset's zero is arbitrary: it has no share of itself to cross.
    if not line or not line.significant or not reference or _is_offset(name):
        return entry
    last = line.at(days[-1])
    away = last - reference
    if abs(away) <= share * abs(reference) or away * line.slope <= 0:
        return entry
    direction = "rising" if line.slope > 0 else "falling"
    entry["drift"] = {
        **({"effect": name.split(".", 1)[0]} if "." in name else {}),
        "parameter": name,
        "direction": direction,
        "slope": line.slope,
        "slope_stderr": line.slope_stderr,
        "evidence": (
            f"{name} {'rose' if line.slope > 0 else 'fell'} from {values[0]:.4g} to {values[-1]:.4g} over "
            f"{line.span_days:.1f} days ({line.slope:+.3g} ± {line.slope_stderr:.2g} a day, t = {line.t:.1f} "
            f"against {t_quantile(line.dof):.1f} over {line.points} recordings"
            f"{f', {line.left_out} failed fit(s) left out' if line.left_out else ''}); its trend now stands "
            f"{100 * away / abs(reference):+.0f} % from the reference {reference:.4g}, past the {100 * share:.0f} % allowed"
        ),
    }
    return entry


def _is_offset(name: str) -> bool:
    return name.endswith("offset") or name == "load_torque"


def _new_effects(good: list[dict], days: list[float], reference: dict) -> list[dict]:
    """Effects the reference lacks that the last recordings all find significant."""
    have = {k.split(".", 1)[0] for k in reference if "." in k}
    tail = good[-NEW_EFFECT_RUN:]
    if len(tail) < NEW_EFFECT_RUN:
        return []
    found = []
    for effect in sorted(set.intersection(*({e["effect"] for e in r["effects"] or []} for r in tail)) - have):
        seen = [(d, next(e for e in r["effects"] if e["effect"] == effect)) for d, r in zip(days, good) if any(e["effect"] == effect for e in r["effects"] or [])]
        # Its parameter that moves the most surely: how it is growing.
        best = None
        for key in seen[-1][1]["params"]:
            line = fit_line([d for d, _ in seen], [e["params"][key] for _, e in seen])
            if line and (best is None or line.t > best[1].t):
                best = (key, line)
        last = seen[-1][1]
        drop = 100 * (1 - last["nrmse_after"] / last["nrmse_before"]) if last["nrmse_before"] else 0.0
        evidence = (
            f"{effect} significant in each of the last {len(tail)} recordings and in {len(seen)} of {len(good)} "
            f"(the last: {last['test']} {last['statistic']:.1f} against {last['threshold']:.1f}, it removes "
            f"{drop:.0f} % of the {last['output']} error)"
        )
        item = {"effect": effect, "direction": "new", "slope": None, "slope_stderr": None, "evidence": evidence}
        if best:
            key, line = best
            item.update(parameter=f"{effect}.{key}", slope=line.slope, slope_stderr=line.slope_stderr if math.isfinite(line.slope_stderr) else None)
            item["evidence"] += f"; {effect}.{key} {last['params'][key]:.4g} now, {line.slope:+.3g} a day"
        found.append(item)
    return found


def _degrading_fit(good: list[dict], days: list[float], share: float) -> dict | None:
    """The refitted reference's validation error rising past its first level by `share`."""
    values = [(r["nrmse"] or {}).get("overall") for r in good]
    points = [(d, v) for d, v in zip(days, values) if v is not None]
    if len(points) < MIN_POINTS:
        return None
    line = fit_line([d for d, _ in points], [v for _, v in points])
    first = sorted(v for _, v in points[:3])[len(points[:3]) // 2]
    if not line or not line.significant or line.slope <= 0 or line.at(points[-1][0]) <= (1 + share) * first:
        return None
    return {
        "parameter": "validation_nrmse",
        "direction": "rising",
        "slope": line.slope,
        "slope_stderr": line.slope_stderr,
        "evidence": (
            f"the reference fits worse: validation NRMSE {first:.3f} at first, {points[-1][1]:.3f} now "
            f"({line.slope:+.3g} a day, t = {line.t:.1f} against {t_quantile(line.dof):.1f})"
        ),
    }
