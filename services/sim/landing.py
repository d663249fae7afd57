"""Landing along the track: where the product metered in each tick lands on the true path, and the
applied rate of each tick there (for the transition figures and the time series). Each section's
own strip, for the as-applied raster, is `services.sim.section_landing`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.maps import Grid

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


def land(grid: Grid, track: dict, metered_kg, width_on_m, delay_s, period_s) -> Landing:
    """Product metered during [t, t + period] lands on the true path during the same span + delay;
    its rate is taken over the width of the sections that were on, centred on the path."""
    time_s, x_m, y_m = track["time_s"], track["x_m"], track["y_m"]
    t0 = np.asarray(time_s) + delay_s
    x0, y0 = np.interp(t0, time_s, x_m), np.interp(t0, time_s, y_m)
    x1, y1 = np.interp(t0 + period_s, time_s, x_m), np.interp(t0 + period_s, time_s, y_m)
    length = np.hypot(x1 - x0, y1 - y0)
    applied = applied_rate_kg_ha(metered_kg, width_on_m, length)
    rx = grid.lookup(0.5 * (x0 + x1), 0.5 * (y0 + y1)).rate_kg_ha
    return Landing(x0, y0, x1, y1, length, np.cumsum(length), rx, applied)
