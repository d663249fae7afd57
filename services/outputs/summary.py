"""The run's summary as text and as JSON (`vrsim run`, `vrsim run --json`, summary.json and the
monitor's report all print it with these)."""

from __future__ import annotations

import math

from vrsim.services.outputs.encode import dumps_text
from vrsim.services.sim import metrics
from vrsim.services.sim.display import shown_figure
from vrsim.services.sim.spread_pattern import CV_LIMIT_PCT


def summary_json(summary: dict) -> str:
    """One JSON object; non-finite figures (e.g. no rate steps crossed) become null."""
    return dumps_text(summary, indent=True)


def summary_rows() -> tuple[tuple[str, str, str], ...]:
    """The report's rows (label, key, unit): the figures of `services.sim.metrics.METRICS` that have a
    label, in its order."""
    return tuple((m.label, m.key, m.unit) for m in metrics.METRICS if m.label)


def shown(summary: dict) -> tuple[tuple[tuple[str, str, str], ...], dict]:
    """The report's rows (label, key, unit) and the values to show for them, in the summary's ``units``
    (`services.sim.display.shown_figure`): the rate figures in the map's own unit (the summary's
    ``rate_unit`` and ``in_rate_unit``; kg/ha in a summary without), or its counterpart in the other
    system; product in lb, area in ac, lengths in ft, speeds in mph in "us"."""
    values, rows = dict(summary), []
    for label, key, row_unit in summary_rows():
        values[key], row_unit = shown_figure(summary, key, row_unit)
        rows.append((label, key, row_unit))
    return tuple(rows), values


def fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:,.2f}"
    if isinstance(value, list):  # section widths
        return ", ".join(f"{v:g}" for v in value)
    return str(value)


def warnings(summary: dict) -> list[str]:
    """What the figures say is wrong with the set-up, one line each (the text summary's last lines, the
    report's banner): a spread CV above EN 13739's `CV_LIMIT_PCT`, with the driving width that meets it."""
    cv_pct = summary.get("cv_pct")
    if not isinstance(cv_pct, float) or not math.isfinite(cv_pct) or cv_pct <= CV_LIMIT_PCT:
        return []
    width, unit = shown_figure(summary, "effective_width_m", "m")
    meets = (f"drive at {fmt(width)} {unit} or narrower to meet it" if isinstance(width, float) and width > 0
             else "no driving width meets it")
    return [f"warning: spread CV {cv_pct:.1f} % is above EN 13739's {CV_LIMIT_PCT:g} % at this driving "
            f"width: the ground between passes gets an uneven rate; {meets}"]


def text_summary(summary: dict) -> str:
    """The readable summary `vrsim run` prints, its `warnings` last."""
    lines = [f"vrsim run: {summary['scenario']} ({summary['ticks']:,} ticks)"]
    rows, values = shown(summary)
    for label, key, unit in rows:
        lines.append(f"  {label:<38} {fmt(values[key]):>14} {unit}")
    return "\n".join(lines + warnings(summary))
