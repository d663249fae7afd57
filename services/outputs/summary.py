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


def fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:,.2f}"
    if isinstance(value, list):  # section widths
        return ", ".join(f"{v:g}" for v in value)
    return str(value)


def text_summary(summary: dict) -> str:
    """The readable summary `vrsim run` prints."""
    lines = [f"vrsim run: {summary['scenario']} ({summary['ticks']:,} ticks)"]
    for label, key, unit in summary_rows():
        lines.append(f"  {label:<38} {fmt(summary[key]):>14} {unit}")
    return "\n".join(lines)
