"""Landing: where the product metered in each tick lands on the true path, as strips of the width on,
and those strips merged for the as-applied raster."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from maps import Grid

MIN_STRIP_M = 0.01  # below 1 cm of travel in a tick (standing still) a tick's rate means nothing
M2_PER_HA = 1e4


def applied_rate_kg_ha(metered_kg, width_m, length_m) -> np.ndarray:
    """The applied rate of a tick: its metered product over the strip it covers, kg/ha.

    Parameters
    ----------
    metered_kg, width_m, length_m : array_like, shape (n,)
        Product metered in each tick, the width of the sections that were on, and the length of the
        strip (m).

    Returns
    -------
    ndarray, shape (n,)
        ``metered_kg / (width_m * length_m)`` in kg/ha; NaN where the strip is shorter than
        `MIN_STRIP_M` or no section is on.
    """
    length = np.asarray(length_m, dtype=float)
    area_m2 = np.asarray(width_m, dtype=float) * length
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((length > MIN_STRIP_M) & (area_m2 > 0), metered_kg / area_m2 * M2_PER_HA, np.nan)


@dataclass
class Landing:
    """Where the product metered in each tick landed, and the rates there along the track."""

    x0_m: np.ndarray
    y0_m: np.ndarray
    x1_m: np.ndarray
    y1_m: np.ndarray
    strip_length_m: np.ndarray
    distance_m: np.ndarray  # landing point's travelled distance at each tick
    prescribed_kg_ha: np.ndarray  # prescription at each strip's midpoint (true position)
    applied_kg_ha: np.ndarray  # metered kg over the strip's area (NaN: shorter than 1 cm, or sections off)


def land(grid: Grid, track: dict, metered_kg, width_on_m, offset_m, delay_s, period_s) -> Landing:
    """Product metered during [t, t + period] lands on the true path during the same span + delay,
    over the width of the sections that were on, shifted by their offset to the left."""
    time_s, x_m, y_m = track["time_s"], track["x_m"], track["y_m"]
    t0 = np.asarray(time_s) + delay_s
    hx = np.interp(t0, time_s, np.cos(track["heading_rad"]))
    hy = np.interp(t0, time_s, np.sin(track["heading_rad"]))
    norm = np.hypot(hx, hy)
    shift = np.divide(offset_m, norm, out=np.zeros(norm.shape), where=norm > 0)
    sx, sy = -hy * shift, hx * shift  # along the left normal
    x0, y0 = np.interp(t0, time_s, x_m) + sx, np.interp(t0, time_s, y_m) + sy
    x1, y1 = np.interp(t0 + period_s, time_s, x_m) + sx, np.interp(t0 + period_s, time_s, y_m) + sy
    length = np.hypot(x1 - x0, y1 - y0)
    applied = applied_rate_kg_ha(metered_kg, width_on_m, length)
    rx = grid.lookup(0.5 * (x0 + x1), 0.5 * (y0 + y1)).rate_kg_ha
    return Landing(x0, y0, x1, y1, length, np.cumsum(length), rx, applied)


def merged_strips(landing: Landing, metered_kg, width_m, offset_m, cell_m: float):
    """Consecutive ticks' strips joined into strips up to half a cell long: (x0, y0, x1, y1, width, kg).

    A tick's strip (0.125 m at 9 km/h and 50 ms) is far shorter than a map cell; joining k of them
    (their ends meet exactly) spreads each group's product evenly over at most half a cell, which
    changes per-cell figures by a blur far below the cell size and cuts the raster work k-fold. A
    group also ends where the sections change, so a joined strip has one width and offset.
    """
    starts = strip_starts(landing, width_m, offset_m, cell_m)
    return (*merged_geometry(landing, width_m, starts), merged_mass(metered_kg, starts))


def strip_starts(landing: Landing, width_m, offset_m, cell_m: float) -> np.ndarray:
    """The first tick of each joined strip (`merged_strips`): every k ticks and where the sections
    change; the geometry alone decides them, not the product."""
    n = len(landing.strip_length_m)
    typical = float(np.median(landing.strip_length_m)) if n else 0.0
    k = max(1, int(0.5 * cell_m / typical)) if typical > 0 else 1
    change = np.flatnonzero((np.diff(width_m) != 0) | (np.diff(offset_m) != 0)) + 1
    return np.union1d(np.arange(0, n, k), change).astype(np.int64)


def merged_geometry(landing: Landing, width_m, starts: np.ndarray):
    """(x0, y0, x1, y1, width) of the strips joined from the ticks at `starts` on."""
    ends = np.append(starts[1:], len(landing.strip_length_m)) - 1
    return (landing.x0_m[starts], landing.y0_m[starts], landing.x1_m[ends], landing.y1_m[ends],
            np.asarray(width_m)[starts])


def merged_mass(metered_kg, starts: np.ndarray) -> np.ndarray:
    """Product of each joined strip, kg: `metered_kg` (ticks along axis 0, any columns) summed over it."""
    return np.add.reduceat(metered_kg, starts, axis=0) if len(metered_kg) else metered_kg
