"""map.png (prescribed, applied and error maps) and timeseries.png (shaft speed and rate around
rate steps).

Drawn on bare `matplotlib.figure.Figure`s with the Agg canvas (no pyplot: its import and global state
cost more than the drawing) and a fixed layout (a layout engine measures every label, twice).
"""

from __future__ import annotations

import numpy as np

from services.sim.metrics import rate_steps
from services.sim.run import RunResult

TIMESERIES_WINDOW_S = 60.0
MAX_TRACK_POINTS = 20_000  # the path over the prescription: more points draw the same line


def figure(width_in: float, height_in: float, **margins):
    """A Figure on the Agg canvas with fixed margins (fractions of the figure)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    fig.subplots_adjust(**margins)
    return fig


def plot_maps(result: RunResult, path: str) -> None:
    grid = result.world.grid
    # Metres from the map's south-west corner: UTM eastings of six digits crowd the axis.
    west, south, east, north = grid.bounds
    extent = (0.0, east - west, 0.0, north - south)
    rx, applied = grid.rates_kg_ha, result.as_applied.applied_kg_ha
    shown = np.where(result.in_field, 1.0, np.nan)
    vmax = float(np.nanmax(rx)) * 1.2 if np.isfinite(np.nanmax(rx)) else 1.0
    err = (applied - rx) * shown
    emax = max(float(np.nanpercentile(np.abs(err), 98)) if np.isfinite(err).any() else 1.0, 1.0)
    fig = figure(17, 5.5, left=0.05, right=0.97, bottom=0.1, top=0.86, wspace=0.25)
    axes = fig.subplots(1, 3)
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
    step = max(1, len(result.track["x_m"]) // MAX_TRACK_POINTS)
    axes[0].plot(result.track["x_m"][::step] - west, result.track["y_m"][::step] - south, color="w", lw=0.3,
                 alpha=0.6)
    axes[0].set_ylabel("north (m) of the map's south-west corner")
    fig.suptitle(f"{result.world.scenario.name}: MAE {result.summary['mae_kg_ha']:.1f} kg/ha, "
                 f"within 10 %: {result.summary['within_10pct_area_pct']:.1f} % of covered area")
    fig.savefig(path, dpi=90)


def _window(result: RunResult) -> slice:
    """A window of the run that holds rate steps (the first one), else the run's start."""
    t = result.track["time_s"]
    steps = rate_steps(result.landing.prescribed_kg_ha, np.asarray(result.track["implement_on"], bool))
    start_t = t[steps[0]] - 10.0 if steps.size else t[0]
    i0 = int(np.searchsorted(t, start_t))
    i1 = int(np.searchsorted(t, t[i0] + TIMESERIES_WINDOW_S))
    return slice(i0, max(i1, i0 + 1))


def plot_timeseries(result: RunResult, path: str) -> None:
    w = _window(result)
    t = result.track["time_s"][w]
    c, landing = result.control, result.landing
    fig = figure(11, 6.5, left=0.08, right=0.97, bottom=0.09, top=0.92, hspace=0.08)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
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
