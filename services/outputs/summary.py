"""The run's summary as text and as JSON (`vrsim run`, `vrsim run --json`, summary.json and the
monitor's report all print it with these)."""

from __future__ import annotations

import math

from services.outputs.encode import dumps_text
from services.sim import metrics


def summary_json(summary: dict) -> str:
    """One JSON object; non-finite figures (e.g. no rate steps crossed) become null."""
    return dumps_text(summary, indent=True)


def summary_rows() -> tuple[tuple[str, str, str], ...]:
    """The report's rows (label, key, unit): the figures of `services.sim.metrics.METRICS` that have a
    label, in its order."""
    return tuple((m.label, m.key, m.unit) for m in metrics.METRICS if m.label)


def shown(summary: dict) -> tuple[tuple[tuple[str, str, str], ...], dict]:
    """The report's rows (label, key, unit) and the values to show for them: the rate figures in the
    map's own unit (the summary's ``rate_unit`` and ``in_rate_unit``; kg/ha in a summary without)."""
    unit, in_unit = summary.get("rate_unit", metrics.RATE_UNIT), summary.get("in_rate_unit", {})
    values, rows = dict(summary), []
    for label, key, row_unit in summary_rows():
        if row_unit == metrics.RATE_UNIT and metrics.rate_key(key) in in_unit:
            values[key], row_unit = in_unit[metrics.rate_key(key)], unit
        rows.append((label, key, row_unit))
    return tuple(rows), values


def fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:,.2f}"
    if isinstance(value, list):  # section widths
        return ", ".join(f"{v:g}" for v in value)
    return str(value)


def text_summary(summary: dict) -> str:
    """The readable summary `vrsim run` prints."""
    lines = [f"vrsim run: {summary['scenario']} ({summary['ticks']:,} ticks)"]
    rows, values = shown(summary)
    for label, key, unit in rows:
        lines.append(f"  {label:<38} {fmt(values[key]):>14} {unit}")
    return "\n".join(lines)
