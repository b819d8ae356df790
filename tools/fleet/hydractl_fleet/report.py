"""`hydractl-fleet report`: one self-contained HTML page (inline SVG, no
script, nothing fetched): the fleet at a glance, then each machine's
parameters over time with its reference, the band allowed around it, and
the trend."""

from __future__ import annotations

import datetime as dt
import html
from pathlib import Path

STATE_COLOURS = {"drifting": "#c62828", "unreadable": "#ef6c00", "steady": "#2e7d32", "no data": "#757575"}
WIDTH, HEIGHT, PAD, RIGHT = 350, 170, 60, 18


def write(fleet: dict, out: Path) -> None:
    machines = fleet["machines"]
    share = fleet["share"]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>hydractl fleet</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>The fleet: {len(machines)} machine(s)</h1>",
        f"<p>A parameter drifts when its trend is significant (t past Student's two-sided 95 % quantile) and stands more "
        f"than {100 * share:.0f} % from the machine's reference; an effect the reference lacks is new once the "
        f"last recordings all find it significant.</p>",
        _overview(machines),
    ]
    for m in machines:
        parts.append(_machine(m, share))
    parts.append("</body></html>")
    out.write_text("\n".join(parts), encoding="utf-8")


def _overview(machines: list[dict]) -> str:
    rows = []
    for m in machines:
        colour = STATE_COLOURS.get(m["state"], "#757575")
        drifts = "<br>".join(
            f"<b>{html.escape(d.get('parameter') or d['effect'])}</b> {d['direction']}" for d in m["drifting"]
        ) or "—"
        rows.append(
            f"<tr><td><a href='#{_anchor(m['machine_id'])}'>{html.escape(m['machine_id'])}</a></td>"
            f"<td><span class='state' style='background:{colour}'>{m['state']}</span></td>"
            f"<td>{m['recordings']}</td><td>{m['errors']}</td><td>{_day(m['last_seen'])}</td><td>{drifts}</td></tr>"
        )
    return (
        "<table class='overview'><tr><th>machine</th><th>state</th><th>recordings</th><th>errors</th>"
        "<th>last seen</th><th>drifting</th></tr>" + "".join(rows) + "</table>"
    )


def _machine(m: dict, share: float) -> str:
    out = [f"<h2 id='{_anchor(m['machine_id'])}'>{html.escape(m['machine_id'])} "
           f"<span class='state' style='background:{STATE_COLOURS.get(m['state'], '#757575')}'>{m['state']}</span></h2>"]
    out.append(f"<p>{m['recordings']} recording(s) from {_day(m['first_seen'])} to {_day(m['last_seen'])}.</p>")
    if m["drifting"]:
        out.append("<ul>" + "".join(f"<li>{html.escape(d['evidence'])}</li>" for d in m["drifting"]) + "</ul>")
    if m.get("inseparable"):
        out.append("<p>Fixed only in a combination with another parameter, shown and not named: "
                   + ", ".join(f"<code>{html.escape(n)}</code>" for n in m["inseparable"]) + ".</p>")
    if m["failures"]:
        out.append("<p class='errors'>Not diagnosed:</p><ul class='errors'>" + "".join(
            f"<li><code>{html.escape(Path(f['recording']).name)}</code>: {html.escape(f['error'])}</li>" for f in m["failures"]) + "</ul>")
    drifting = {d.get("parameter") for d in m["drifting"]}
    # The drifting first, then the effects' parameters, then the rest.
    names = sorted(m["series"], key=lambda n: (n not in drifting, "." not in n, n))
    first = dt.datetime.fromisoformat(m["first_seen"].replace("Z", "+00:00")) if m["first_seen"] else None
    out.append("<div class='charts'>" + "".join(_chart(n, m["series"][n], share, n in drifting, first) for n in names) + "</div>")
    return "\n".join(out)


def _chart(name: str, s: dict, share: float, drifting: bool, first: dt.datetime | None) -> str:
    days, values, ref = s["days"], s["values"], s["reference"]
    if not days:
        return ""
    lo, hi = min(values), max(values)
    if ref:
        lo, hi = min(lo, ref * (1 - share), ref * (1 + share)), max(hi, ref * (1 - share), ref * (1 + share))
    if hi == lo:
        hi, lo = hi + abs(hi) * 0.1 + 1e-12, lo - abs(lo) * 0.1 - 1e-12
    margin = 0.08 * (hi - lo)
    lo, hi = lo - margin, hi + margin
    d0, d1 = min(days), max(max(days), min(days) + 1.0)

    def x(d: float) -> float:
        return PAD + (d - d0) / (d1 - d0) * (WIDTH - PAD - RIGHT)

    def y(v: float) -> float:
        return HEIGHT - 22 - (v - lo) / (hi - lo) * (HEIGHT - 22 - 18)

    parts = [f"<svg width='{WIDTH}' height='{HEIGHT}' viewBox='0 0 {WIDTH} {HEIGHT}'>"]
    parts.append(f"<rect x='{PAD}' y='18' width='{WIDTH - PAD - RIGHT}' height='{HEIGHT - 40}' fill='#fafafa' stroke='#ddd'/>")
    if ref:
        top, bottom = y(ref * (1 + share)), y(ref * (1 - share))
        parts.append(f"<rect x='{PAD}' y='{min(top, bottom):.1f}' width='{WIDTH - PAD - RIGHT}' height='{abs(bottom - top):.1f}' fill='#e8f5e9'/>")
        parts.append(f"<line x1='{PAD}' x2='{WIDTH - RIGHT}' y1='{y(ref):.1f}' y2='{y(ref):.1f}' stroke='#2e7d32' stroke-dasharray='4 3'/>")
    if s["slope"] is not None:
        a, b = s["intercept"], s["slope"]
        parts.append(f"<line x1='{x(d0):.1f}' x2='{x(max(days)):.1f}' y1='{y(a + b * d0):.1f}' y2='{y(a + b * max(days)):.1f}' "
                     f"stroke='{'#c62828' if drifting else '#1565c0'}' stroke-width='1.5'/>")
    for d, v in zip(days, values):
        parts.append(f"<circle cx='{x(d):.1f}' cy='{y(v):.1f}' r='2.6' fill='#263238'/>")
    parts.append(f"<text x='{PAD}' y='13' class='title'>{html.escape(name)}{' — drifting' if drifting else ''}</text>")
    for v in (lo + margin, hi - margin):
        parts.append(f"<text x='{PAD - 3}' y='{y(v) + 3:.1f}' class='tick' text-anchor='end'>{v:.3g}</text>")
    if first:
        for d in (d0, max(days)):
            label = (first + dt.timedelta(days=d)).strftime("%m-%d")
            parts.append(f"<text x='{x(d):.1f}' y='{HEIGHT - 8}' class='tick' text-anchor='middle'>{label}</text>")
    parts.append("</svg>")
    return "".join(parts)


def _anchor(machine_id: str) -> str:
    return "m-" + "".join(c if c.isalnum() else "-" for c in machine_id)


def _day(iso: str | None) -> str:
    return iso[:16].replace("T", " ") if iso else "—"


_CSS = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 24px; color: #222; max-width: 1100px; }
table.overview { border-collapse: collapse; margin: 12px 0 28px; }
table.overview td, table.overview th { border-bottom: 1px solid #ddd; padding: 5px 12px; text-align: left; vertical-align: top; }
.state { color: white; border-radius: 3px; padding: 1px 7px; font-size: 12px; }
.charts { display: flex; flex-wrap: wrap; gap: 6px; }
svg text.title { font-size: 12px; font-weight: 600; }
svg text.tick { font-size: 10px; fill: #555; }
.errors { color: #b71c1c; }
h2 { margin-top: 32px; border-top: 1px solid #eee; padding-top: 16px; }
"""
