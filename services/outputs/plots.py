"""map.png (prescribed, applied and error maps), sections.png (overlap, skips and machine-limited
areas) and timeseries.png (shaft speed and rate around rate steps)."""

from __future__ import annotations

import numpy as np

from services.sim.metrics import rate_steps
from services.sim.run import RunResult

TIMESERIES_WINDOW_S = 60.0


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _frame(result: RunResult):
    """Extent in metres from the map's south-west corner (UTM eastings of six digits crowd the axis),
    that corner, and the field's outline in those metres."""
    west, south, east, north = result.world.grid.bounds
    fx, fy = result.world.field.polygon.exterior.xy
    outline = (np.asarray(fx) - west, np.asarray(fy) - south)
    return (0.0, east - west, 0.0, north - south), (west, south), outline


def _draw(fig, axes, panels, extent, outline, unit: str) -> None:
    """One map per axis: panels of (data, title, colour map, low, high), the field's outline on each."""
    for ax, (data, title, cmap, lo, hi) in zip(axes, panels, strict=True):
        im = ax.imshow(data, extent=extent, origin="upper", cmap=cmap, vmin=lo, vmax=hi,
                       interpolation="nearest")
        ax.plot(*outline, color="k", lw=0.8)
        ax.set_title(title)
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        fig.colorbar(im, ax=ax, label=unit, shrink=0.85)
    axes[0].set_ylabel("north (m) of the map's south-west corner")


def plot_maps(result: RunResult, path: str) -> None:
    plt = _pyplot()
    grid = result.world.grid
    extent, (west, south), (fx, fy) = _frame(result)
    rx, applied = grid.rates_kg_ha, result.as_applied.applied_kg_ha
    shown = np.where(result.in_field, 1.0, np.nan)
    vmax = float(np.nanmax(rx)) * 1.2 if np.isfinite(np.nanmax(rx)) else 1.0
    err = (applied - rx) * shown
    emax = max(float(np.nanpercentile(np.abs(err), 98)) if np.isfinite(err).any() else 1.0, 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.5), constrained_layout=True)
    panels = ((rx * shown, "Prescribed", "viridis", 0, vmax),
              (applied * shown, "Applied", "viridis", 0, vmax),
              (err, "Applied - prescribed", "RdBu_r", -emax, emax))
    _draw(fig, axes, panels, extent, (fx, fy), "kg/ha")
    axes[0].plot(result.track["x_m"] - west, result.track["y_m"] - south, color="w", lw=0.3, alpha=0.6)
    fig.suptitle(f"{result.world.scenario.name}: MAE {result.summary['mae_kg_ha']:.1f} kg/ha, "
                 f"within 10 %: {result.summary['within_10pct_area_pct']:.1f} % of covered area")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_sections(result: RunResult, path: str) -> None:
    """Three maps of where the run went wrong for reasons other than the rate: ground more than one
    pass treated, worked ground no product reached, and ground the meter could not treat at the rate
    asked (its shaft at a limit of its speed range); each as the share of the cell's area."""
    plt = _pyplot()
    extent, _, (fx, fy) = _frame(result)
    shown = np.where(result.in_field, 1.0, np.nan)
    cover = result.as_applied.coverage_fraction
    s = result.summary
    overlap = f"Overlap: {s['overlap_area_pct']:.2f} % of covered area, {s['overlap_kg']:.1f} kg"
    panels = ((result.as_applied.overlap_fraction * shown, overlap, "Reds", 0.0, 1.0),
              (np.maximum(np.minimum(result.worked_fraction, 1.0) - cover, 0.0) * shown,
               f"Skipped: {s['skip_area_pct']:.2f} % of worked area", "Blues", 0.0, 1.0),
              (np.minimum(result.limited_fraction, 1.0) * shown,
               f"Machine-limited: {s['limited_area_pct']:.2f} % of covered area", "Purples", 0.0, 1.0))
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.5), constrained_layout=True)
    _draw(fig, axes, panels, extent, (fx, fy), "share of the cell")
    widths = ", ".join(f"{w:g}" for w in s["section_widths_m"])
    fig.suptitle(f"{result.world.scenario.name}: {s['sections']} sections ({widths} m), section control "
                 f"{result.world.scenario.implement.section_control!r}")
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
