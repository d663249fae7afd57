"""The run's summary as text and as JSON (`vrsim run`, `vrsim run --json`, summary.json and the
monitor's report all print it with these)."""

from __future__ import annotations

import json
import math

import numpy as np


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    return value


def summary_json(summary: dict) -> str:
    """One JSON object; non-finite figures (e.g. no rate steps crossed) become null."""
    return json.dumps(_json_safe(summary), indent=2)


SUMMARY_ROWS = (
    ("Field area", "field_area_ha", "ha"), ("Simulated time", "sim_time_s", "s"),
    ("Wall time", "wall_time_s", "s"), ("Real-time factor", "realtime_factor", "x"),
    ("Prescribed product", "prescribed_kg", "kg"), ("Applied product", "applied_kg", "kg"),
    ("Mass balance", "mass_balance_pct", "%"), ("Mean absolute error", "mae_kg_ha", "kg/ha"),
    ("RMSE", "rmse_kg_ha", "kg/ha"), ("Bias", "bias_kg_ha", "kg/ha"),
    ("Covered area within +-5 %", "within_5pct_area_pct", "%"),
    ("Covered area within +-10 %", "within_10pct_area_pct", "%"),
    ("Transition time, mean", "transition_time_s_mean", "s"),
    ("Transition time, 95th percentile", "transition_time_s_p95", "s"),
    ("Transition distance, mean", "transition_distance_m_mean", "m"),
    ("Transition distance, 95th percentile", "transition_distance_m_p95", "m"),
    ("Off-target product", "off_target_kg", "kg"), ("Coverage", "coverage_pct", "%"),
)


def fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:,.2f}"
    return str(value)


def text_summary(summary: dict) -> str:
    """The readable summary `vrsim run` prints."""
    lines = [f"vrsim run: {summary['scenario']} ({summary['ticks']:,} ticks)"]
    for label, key, unit in SUMMARY_ROWS:
        lines.append(f"  {label:<38} {fmt(summary[key]):>14} {unit}")
    return "\n".join(lines)
