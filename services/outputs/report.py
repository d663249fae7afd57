"""Writes a run's outputs: summary.json, as_applied.tif, error.tif, track.csv, map.png,
timeseries.png and report.html (one self-contained page: the pictures are embedded)."""

from __future__ import annotations

import base64
import html
import json
import math
import os
from dataclasses import replace

import numpy as np

from maps import write_map
from services.sim.metrics import rate_steps
from services.sim.run import RunResult
from services.sim.scenario import as_dict

TRACK_COLUMNS = ("time_s", "lat", "lon", "speed_m_s", "target_shaft_rpm", "shaft_rpm", "current_a",
                 "prescribed_kg_ha", "applied_kg_ha", "implement_on")
TIMESERIES_WINDOW_S = 60.0


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


def write_outputs(result: RunResult, out_dir: str) -> dict[str, str]:
    """Write every output file into `out_dir`; returns {name: path}."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {name: os.path.join(out_dir, name) for name in
             ("summary.json", "as_applied.tif", "error.tif", "track.csv", "map.png", "timeseries.png",
              "report.html")}
    doc = dict(result.summary, scenario_config=as_dict(result.world.scenario))
    with open(paths["summary.json"], "w") as fh:
        fh.write(summary_json(doc) + "\n")
    grid = result.world.grid
    applied = result.as_applied.applied_kg_ha
    write_map(replace(grid, rates_kg_ha=applied, product="as-applied"), paths["as_applied.tif"])
    write_map(replace(grid, rates_kg_ha=applied - grid.rates_kg_ha, product="applied minus prescribed"),
              paths["error.tif"])
    write_track_csv(result, paths["track.csv"])
    if result.world.scenario.output.plots:
        plot_maps(result, paths["map.png"])
        plot_timeseries(result, paths["timeseries.png"])
    else:
        del paths["map.png"], paths["timeseries.png"]
    if result.world.scenario.output.html:
        write_html(result, paths)
    else:
        del paths["report.html"]
    return paths


def write_track_csv(result: RunResult, path: str) -> None:
    track, control, landing = result.track, result.control, result.landing
    lon, lat = result.world.field.to_wgs84(track["x_m"], track["y_m"])
    columns = np.column_stack([track["time_s"], lat, lon, track["speed_m_s"], control["target_shaft_rpm"],
                               control["shaft_rpm"], control["current_a"], landing.prescribed_kg_ha,
                               landing.applied_kg_ha, np.asarray(track["implement_on"], float)])
    fmt = ["%.3f", "%.8f", "%.8f", "%.3f", "%.3f", "%.3f", "%.5f", "%.2f", "%.2f", "%d"]
    np.savetxt(path, columns, fmt=fmt, delimiter=",", header=",".join(TRACK_COLUMNS), comments="")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_maps(result: RunResult, path: str) -> None:
    plt = _pyplot()
    grid = result.world.grid
    # Metres from the map's south-west corner: UTM eastings of six digits crowd the axis.
    west, south, east, north = grid.bounds
    extent = (0.0, east - west, 0.0, north - south)
    rx, applied = grid.rates_kg_ha, result.as_applied.applied_kg_ha
    shown = np.where(result.in_field, 1.0, np.nan)
    vmax = float(np.nanmax(rx)) * 1.2 if np.isfinite(np.nanmax(rx)) else 1.0
    err = (applied - rx) * shown
    emax = max(float(np.nanpercentile(np.abs(err), 98)) if np.isfinite(err).any() else 1.0, 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.5), constrained_layout=True)
    panels = ((rx * shown, "Prescribed", "viridis", 0, vmax),
              (applied * shown, "Applied", "viridis", 0, vmax),
              (err, "Applied - prescribed", "RdBu_r", -emax, emax))
    fx, fy = result.world.field.polygon.exterior.xy
    fx, fy = np.asarray(fx) - west, np.asarray(fy) - south
    for ax, (data, title, cmap, lo, hi) in zip(axes, panels, strict=True):
        im = ax.imshow(data, extent=extent, origin="upper", cmap=cmap, vmin=lo, vmax=hi,
                       interpolation="nearest")
        ax.plot(fx, fy, color="k", lw=0.8)
        ax.set_title(title)
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        fig.colorbar(im, ax=ax, label="kg/ha", shrink=0.85)
    axes[0].plot(result.track["x_m"] - west, result.track["y_m"] - south, color="w", lw=0.3, alpha=0.6)
    axes[0].set_ylabel("north (m) of the map's south-west corner")
    fig.suptitle(f"{result.world.scenario.name}: MAE {result.summary['mae_kg_ha']:.1f} kg/ha, "
                 f"within 10 %: {result.summary['within_10pct_area_pct']:.1f} % of covered area")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _window(result: RunResult) -> slice:
    """A window of the run that holds rate steps (the first one), else the run's start."""
    t = result.track["time_s"]
    steps = rate_steps(result.landing.prescribed_kg_ha, np.asarray(result.track["implement_on"], bool))
    start_t = t[steps[0]] - 10.0 if steps.size else t[0]
    i0 = int(np.searchsorted(t, start_t))
    i1 = int(np.searchsorted(t, t[i0] + TIMESERIES_WINDOW_S))
    return slice(i0, max(i1, i0 + 1))


def plot_timeseries(result: RunResult, path: str) -> None:
    plt = _pyplot()
    w = _window(result)
    t = result.track["time_s"][w]
    c, landing = result.control, result.landing
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True, constrained_layout=True)
    ax1.plot(t, c["target_shaft_rpm"][w], label="target", lw=1.2)
    ax1.plot(t, c["shaft_rpm"][w], label="actual", lw=1.0)
    ax1.set_ylabel("metering shaft (rpm)")
    ax1.legend(loc="upper right")
    ax2.plot(t, landing.prescribed_kg_ha[w], label="prescribed (where it lands)", lw=1.2)
    ax2.plot(t, landing.applied_kg_ha[w], label="applied", lw=1.0)
    ax2.set_ylabel("rate (kg/ha)")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="upper right")
    fig.suptitle(f"{result.world.scenario.name}: shaft speed and rate around rate steps")
    fig.savefig(path, dpi=90)
    plt.close(fig)


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


def _fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:,.2f}"
    return str(value)


def text_summary(summary: dict) -> str:
    """The readable summary `vrsim run` prints."""
    lines = [f"vrsim run: {summary['scenario']} ({summary['ticks']:,} ticks)"]
    for label, key, unit in SUMMARY_ROWS:
        lines.append(f"  {label:<38} {_fmt(summary[key]):>14} {unit}")
    return "\n".join(lines)


def write_html(result: RunResult, paths: dict[str, str]) -> None:
    rows = "\n".join(f"<tr><td>{html.escape(label)}</td><td>{_fmt(result.summary[key])}</td>"
                     f"<td>{unit}</td></tr>" for label, key, unit in SUMMARY_ROWS)
    images = ""
    for name in ("map.png", "timeseries.png"):
        if name in paths and os.path.isfile(paths[name]):
            with open(paths[name], "rb") as fh:
                data = base64.b64encode(fh.read()).decode()
            images += f'<figure><img alt="{name}" src="data:image/png;base64,{data}"></figure>\n'
    title = html.escape(f"vrsim run: {result.summary['scenario']}")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1500px}}table{{border-collapse:collapse}}
td{{padding:2px 10px;border-bottom:1px solid #ddd}}td:nth-child(2){{text-align:right}}
img{{max-width:100%}}</style>
</head><body><h1>{title}</h1>
<p>{html.escape(result.world.scenario.description)}</p>
<table>{rows}</table>
{images}
<p>Files beside this page: summary.json, track.csv, as_applied.tif, error.tif (GeoTIFF, kg/ha).</p>
</body></html>
"""
    with open(paths["report.html"], "w") as fh:
        fh.write(page)
