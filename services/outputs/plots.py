"""map.png (prescribed, applied and error maps), sections.png (overlap, skips and machine-limited
areas) and timeseries.png (shaft speed and rate around rate steps).

The pictures are drawn from plain arrays (`MapPicture`, `SectionsPicture`, `SeriesPicture`, taken
from a run by `map_picture`, `sections_picture` and `series_picture`), so they can be drawn in another
process (`services.outputs.plot_worker`). Drawn on bare `matplotlib.figure.Figure`s with the Agg
canvas (no pyplot: its import and global state cost more than the drawing) and a fixed layout (a
layout engine measures every label, twice). This module imports only numpy at the top, so the worker
starts light.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def figure(width_in: float, height_in: float, layout: str | None = None, **margins):
    """A Figure on the Agg canvas (no pyplot): fixed margins (fractions of the figure), or a layout
    engine by name (``"constrained"``) where the number of panels varies."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout=layout)
    if margins:
        fig.subplots_adjust(**margins)
    return fig


@dataclass
class MapPicture:
    """What map.png shows: rasters (rows, cols) in the rate `unit` shown (the map's, or its counterpart
    in the run's units) on a map `extent_m` wide and high, the field boundary and the path from the map's
    south-west corner, lengths in `length_unit` (m, or ft in US units; `extent_m` too); the error's
    colour scale spans at least `error_floor` (1 kg/ha in `unit`) either way."""

    prescribed: np.ndarray
    applied: np.ndarray
    in_field: np.ndarray
    extent_m: tuple
    field_xy: tuple
    path_xy: tuple
    title: str
    unit: str
    error_floor: float
    length_unit: str = "m"


@dataclass
class SectionsPicture:
    """What sections.png shows: per cell (rows, cols), the share of its area that more than one pass
    treated, that was worked but no product reached, and that product metered at a clipped target
    (the shaft at a limit of its speed range) covered; panel titles with the summary's figures."""

    overlap: np.ndarray
    skipped: np.ndarray
    limited: np.ndarray
    in_field: np.ndarray
    extent_m: tuple
    field_xy: tuple
    titles: tuple
    title: str
    length_unit: str = "m"  # of `extent_m` and `field_xy`, as `MapPicture`'s


@dataclass
class SeriesPicture:
    """What timeseries.png shows: a window of the run, per tick, the rates in the map's `unit`."""

    time_s: np.ndarray
    target_shaft_rpm: np.ndarray
    shaft_rpm: np.ndarray
    prescribed: np.ndarray
    applied: np.ndarray
    title: str
    unit: str


def _frame(result):
    """Extent from the map's south-west corner (UTM eastings of six digits crowd the axis), that corner
    (m), the field's outline from it, and a function that takes metres from it to the lengths shown
    (`_lengths`) with their unit."""
    west, south, east, north = result.world.grid.bounds
    fx, fy = result.world.field.polygon.exterior.xy
    shown, unit = _lengths(result.summary.get("units", "metric"))
    outline = (shown(np.asarray(fx) - west), shown(np.asarray(fy) - south))
    extent = tuple(shown(v) for v in (0.0, east - west, 0.0, north - south))
    return extent, (west, south), outline, shown, unit


def _lengths(units: str):
    """(metres -> the length shown in `units`, its unit): `maps.units.in_units` of m."""
    from vrsim.maps.units import in_units

    factor, unit = in_units(1.0, "m", units)
    return (lambda metres: metres * factor), unit


def _rates(values, grid, units: str):
    """The rates `values` (kg/ha) in the map's unit, or its counterpart in `units`: (values, unit)."""
    from vrsim.maps.units import in_units

    return in_units(np.asarray(grid.in_map_unit(values), float), grid.map_unit, units)


def map_picture(result) -> MapPicture:
    """map.png's content of a `services.sim.run.RunResult`."""
    from vrsim.services.sim.display import shown_figure

    grid = result.world.grid
    extent, (west, south), outline, shown, length_unit = _frame(result)
    x_m, y_m = result.kept.path_xy   # thinned (`services.sim.kept.PathPoints`)
    s = result.summary
    units = s.get("units", "metric")
    # The deposit's rasters, read once by the run (each read of `result.as_applied` sums them again).
    (rx, unit), (applied, _) = (_rates(v, grid, units) for v in (grid.rates_kg_ha,
                                                                  result.accounts.deposit.applied_kg_ha))
    mae, _ = shown_figure(s, "mae_kg_ha", "kg/ha")
    return MapPicture(rx, applied, result.in_field, extent, outline, (shown(x_m - west), shown(y_m - south)),
                      f"{result.world.scenario.name}: MAE {mae:.1f} {unit}, "
                      f"within 10 %: {s['within_10pct_area_pct']:.1f} % of covered area",
                      unit, float(_rates(1.0, grid, units)[0]), length_unit)


def sections_picture(result) -> SectionsPicture:
    """sections.png's content of a `services.sim.run.RunResult`."""
    from vrsim.services.sim.display import shown_figure

    extent, _, outline, _, length_unit = _frame(result)
    deposit = result.accounts.deposit
    cover = deposit.coverage_fraction
    s = result.summary
    overlap, mass_unit = shown_figure(s, "overlap_kg", "kg")
    titles = (f"Overlap: {s['overlap_area_pct']:.2f} % of covered area, {overlap:.1f} {mass_unit}",
              # Lines no wider than the panel: the colour bar beside it would hide their ends.
              f"Of worked area: skipped {s['skip_area_pct']:.2f} %\n(where the map asks for product),\n"
              f"bare as prescribed (rate 0) {s['off_as_prescribed_area_pct']:.2f} %",
              f"Machine-limited: {s['limited_area_pct']:.2f} % of covered area")
    section_widths, width_unit = shown_figure(s, "section_widths_m", "m")
    widths = ", ".join(f"{w:.3g}" for w in section_widths)
    return SectionsPicture(deposit.overlap_fraction,
                           np.maximum(np.minimum(result.worked_fraction, 1.0) - cover, 0.0),
                           np.minimum(result.limited_fraction, 1.0), result.in_field, extent, outline, titles,
                           f"{result.world.scenario.name}: {s['sections']} sections ({widths} {width_unit}), "
                           f"section control {result.world.scenario.implement.section_control!r}",
                           length_unit)


def series_picture(result) -> SeriesPicture:
    """timeseries.png's content: a minute from 10 s before the first rate step (else the run's start),
    `services.sim.kept.SeriesWindow`, the rates in the map's unit."""
    return window_picture(result.kept.series, result.world)


def window_picture(w: dict, world) -> SeriesPicture:
    """timeseries.png's content of a `services.sim.kept.SeriesWindow`'s ``series`` `w` of a run of
    `world` (`services.sim.world.World`)."""
    from vrsim.services.sim.display import run_units

    grid, units = world.grid, run_units(world)
    (rx, unit), (applied, _) = (_rates(w[k], grid, units) for k in ("prescribed_kg_ha", "applied_kg_ha"))
    return SeriesPicture(w["time_s"], w["target_shaft_rpm"], w["shaft_rpm"], rx, applied,
                         f"{world.scenario.name}: shaft speed and rate around rate steps", unit)


def _save(fig, path) -> None:
    """Write `fig` as a PNG at 90 dpi, deflated at zlib's level 1: about half the encoding's CPU of
    its default level 6 (0.013 s of map.png's 0.2 s) for up to a sixth more bytes."""
    fig.savefig(path, dpi=90, pil_kwargs={"compress_level": 1})


def _draw_panels(fig, panels, extent, outline, unit: str, length_unit: str = "m"):
    """Three maps side by side: panels of (data, title, colour map, low, high), the field's outline
    on each, lengths in `length_unit`; returns the axes."""
    axes = fig.subplots(1, 3)
    for ax, (data, title, cmap, lo, hi) in zip(axes, panels, strict=True):
        # Nearest cells coloured after resampling (the same pixels as before it, matplotlib's choice
        # near 1:1): a single channel resampled, half the image's CPU.
        im = ax.imshow(data, extent=extent, origin="upper", cmap=cmap, vmin=lo, vmax=hi,
                       interpolation="nearest", interpolation_stage="data")
        ax.plot(*outline, color="k", lw=0.8)
        # At the axes' top (y=1): no title placement, which measures every tick label of the figure's
        # axes to keep the title clear of top ticks these maps do not have.
        ax.set_title(title, y=1.0)
        ax.set_aspect("equal")
        ax.set_xlabel(f"east ({length_unit})")
        # Placed from the panel's box (same place, same pixels) rather than by splitting its gridspec
        # cell into a new gridspec: fewer objects to build.
        fig.colorbar(im, ax=ax, label=unit, shrink=0.85, use_gridspec=False)
    axes[0].set_ylabel(f"north ({length_unit}) of the map's south-west corner")
    return axes


def _three_maps() -> object:
    return figure(17, 4.8, left=0.05, right=0.97, bottom=0.11, top=0.87, wspace=0.25)


def draw_maps(pic: MapPicture, path: str) -> None:
    shown = np.where(pic.in_field, 1.0, np.nan)
    rx, applied = pic.prescribed, pic.applied
    vmax = float(np.nanmax(rx)) * 1.2 if np.isfinite(np.nanmax(rx)) else 1.0
    err = (applied - rx) * shown
    emax = max(float(np.nanpercentile(np.abs(err), 98)) if np.isfinite(err).any() else 1.0, pic.error_floor)
    fig = _three_maps()
    panels = ((rx * shown, "Prescribed", "viridis", 0, vmax),
              (applied * shown, "Applied", "viridis", 0, vmax),
              (err, "Applied - prescribed", "RdBu_r", -emax, emax))
    axes = _draw_panels(fig, panels, pic.extent_m, pic.field_xy, pic.unit, pic.length_unit)
    axes[0].plot(*pic.path_xy, color="w", lw=0.3, alpha=0.6)
    fig.suptitle(pic.title)
    _save(fig, path)


def draw_sections(pic: SectionsPicture, path: str) -> None:
    """Where the run went wrong for reasons other than the rate, each as the share of the cell's area."""
    shown = np.where(pic.in_field, 1.0, np.nan)
    fig = _three_maps()
    panels = tuple((data * shown, title, cmap, 0.0, 1.0) for data, title, cmap in
                   zip((pic.overlap, pic.skipped, pic.limited), pic.titles, ("Reds", "Blues", "Purples"),
                       strict=True))
    _draw_panels(fig, panels, pic.extent_m, pic.field_xy, "share of the cell", pic.length_unit)
    fig.suptitle(pic.title)
    _save(fig, path)


def draw_timeseries(pic: SeriesPicture, path: str) -> None:
    fig = figure(11, 6.5, left=0.08, right=0.97, bottom=0.09, top=0.92, hspace=0.08)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.plot(pic.time_s, pic.target_shaft_rpm, label="target", lw=1.2)
    ax1.plot(pic.time_s, pic.shaft_rpm, label="actual", lw=1.0)
    ax1.set_ylabel("metering shaft (rpm)")
    ax1.legend(loc="upper right")
    ax2.plot(pic.time_s, pic.prescribed, label="prescribed (where it lands)", lw=1.2)
    ax2.plot(pic.time_s, pic.applied, label="applied", lw=1.0)
    ax2.set_ylabel(f"rate ({pic.unit})")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="upper right")
    fig.suptitle(pic.title)
    _save(fig, path)
