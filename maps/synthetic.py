"""Synthetic prescription maps for tests and scenarios: deterministic for a given seed.

Every generator takes ``(bounds, crs, cell_size_m, seed, ...)``: `bounds` = (minx, miny, maxx, maxy)
in `crs`, a projected (metric) CRS such as the field's UTM zone (`maps.utm_crs_for`); `seed` seeds a
`numpy.random.Generator`. The grid's west/north edges are at minx/maxy; it covers the bounds.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim.common import MapError, check_number, check_positive
from vrsim.maps.crs import as_crs, metres_per_unit
from vrsim.maps.grid import Grid, grid_from_bounds

# The generators a scenario names (`[map] synthetic = "zones"`, looked up by name).
__all__ = ["uniform", "zones", "gradient", "random_field", "checkerboard"]


def _blank(kind: str, bounds, crs, cell_size_m: float) -> tuple[Grid, np.ndarray, np.ndarray]:
    """An all-zero grid and its cell-centre coordinates (x: (1, cols), y: (rows, 1)) in metres."""
    crs = as_crs(crs, f"synthetic.{kind}: crs")
    factor = metres_per_unit(crs)
    if factor is None:
        raise MapError(f"synthetic.{kind}: crs {crs.name!r} is geographic; use a projected CRS in "
                       "metres, e.g. maps.utm_crs_for(lon, lat)")
    check_positive(cell_size_m, f"synthetic.{kind}: cell_size_m", MapError)
    grid = grid_from_bounds(bounds, cell_size_m / factor, crs, source=f"synthetic:{kind}", format="synthetic")
    x, y = grid.cell_centres()
    return grid, (x[None, :] - grid.bounds[0]) * factor, (y[:, None] - grid.bounds[1]) * factor


def _check_rates(kind: str, **rates) -> None:
    for name, value in rates.items():
        check_number(value, f"synthetic.{kind}: {name}", MapError, lo=0.0, unit="kg/ha")


def uniform(bounds, crs, cell_size_m: float = 5.0, seed: int = 0, rate_kg_ha: float = 150.0) -> Grid:
    """One rate everywhere (`seed` is unused; accepted so every generator has the same signature)."""
    _check_rates("uniform", rate_kg_ha=rate_kg_ha)
    grid, _, _ = _blank("uniform", bounds, crs, cell_size_m)
    grid.rates_kg_ha[:] = rate_kg_ha
    return grid


def zones(bounds, crs, cell_size_m: float = 5.0, seed: int = 0, n_zones: int = 6,
          rate_range_kg_ha: tuple[float, float] = (100.0, 250.0), rate_step_kg_ha: float = 10.0) -> Grid:
    """Management zones with sharp boundaries: Voronoi cells of `n_zones` random centres.

    Each zone's rate is drawn uniformly from `rate_range_kg_ha` and rounded to `rate_step_kg_ha`;
    every grid cell takes the rate of the zone whose centre is nearest to the cell's centre.
    """
    low, high = rate_range_kg_ha
    _check_rates("zones", low=low, high=high, rate_step_kg_ha=rate_step_kg_ha)
    if not (isinstance(n_zones, int) and n_zones >= 1) or high < low:
        raise MapError(f"synthetic.zones: need n_zones >= 1 and low <= high, got {n_zones}, "
                       f"{rate_range_kg_ha}")
    grid, x, y = _blank("zones", bounds, crs, cell_size_m)
    rng = np.random.default_rng(seed)
    extent_m = (grid.cols * cell_size_m, grid.rows * cell_size_m)
    centres = rng.uniform((0.0, 0.0), extent_m, size=(n_zones, 2))
    rates = rng.uniform(low, high, n_zones)
    if rate_step_kg_ha > 0:
        rates = np.clip(np.round(rates / rate_step_kg_ha) * rate_step_kg_ha, low, high)
    # The nearest of a handful of centres by brute force: a k-d tree (scipy.spatial, a quarter of a
    # second to import) pays off only for many zones.
    x, y = np.broadcast_arrays(x, y)
    nearest = np.zeros(x.shape, np.intp)
    best = (x - centres[0, 0]) ** 2 + (y - centres[0, 1]) ** 2
    for k in range(1, n_zones):
        d2 = (x - centres[k, 0]) ** 2 + (y - centres[k, 1]) ** 2
        closer = d2 < best
        nearest[closer], best[closer] = k, d2[closer]
    grid.rates_kg_ha[:] = rates[nearest]
    return grid


def gradient(bounds, crs, cell_size_m: float = 5.0, seed: int = 0, low_kg_ha: float = 100.0,
             high_kg_ha: float = 250.0, angle_deg: float | None = None) -> Grid:
    """A linear ramp from `low_kg_ha` to `high_kg_ha` across the grid.

    `angle_deg` is the direction of increase, counter-clockwise from east; None draws it from `seed`.
    """
    _check_rates("gradient", low_kg_ha=low_kg_ha, high_kg_ha=high_kg_ha)
    grid, x, y = _blank("gradient", bounds, crs, cell_size_m)
    if angle_deg is None:
        angle_deg = float(np.random.default_rng(seed).uniform(0.0, 360.0))
    a = math.radians(angle_deg)
    s = x * math.cos(a) + y * math.sin(a)
    span = s.max() - s.min()
    t = (s - s.min()) / span if span > 0 else np.zeros_like(s)
    grid.rates_kg_ha[:] = low_kg_ha + (high_kg_ha - low_kg_ha) * t
    return grid


def random_field(bounds, crs, cell_size_m: float = 5.0, seed: int = 0, mean_kg_ha: float = 150.0,
                 std_kg_ha: float = 30.0, correlation_length_m: float = 50.0) -> Grid:
    """A smooth Gaussian random field: white noise blurred over `correlation_length_m`, rescaled to
    the given mean and standard deviation, clipped at 0."""
    _check_rates("random_field", mean_kg_ha=mean_kg_ha, std_kg_ha=std_kg_ha,
                 correlation_length_m=correlation_length_m)
    grid, _, _ = _blank("random_field", bounds, crs, cell_size_m)
    from scipy.ndimage import gaussian_filter  # here, not at import: scipy costs ~0.5 s to import

    noise = np.random.default_rng(seed).standard_normal((grid.rows, grid.cols))
    smooth = gaussian_filter(noise, sigma=correlation_length_m / cell_size_m, mode="reflect")
    sd = smooth.std()
    z = (smooth - smooth.mean()) / sd if sd > 0 else np.zeros_like(smooth)
    grid.rates_kg_ha[:] = np.maximum(mean_kg_ha + std_kg_ha * z, 0.0)
    return grid


def checkerboard(bounds, crs, cell_size_m: float = 5.0, seed: int = 0, square_m: float = 20.0,
                 low_kg_ha: float = 100.0, high_kg_ha: float = 200.0) -> Grid:
    """Squares of `square_m` alternating between two rates, starting with `low_kg_ha` in the south-west
    corner (`seed` is unused; accepted so every generator has the same signature).

    With `square_m` a multiple of `cell_size_m` every square is exactly whole cells: the sharpest
    test of a controller's step response along a pass.
    """
    _check_rates("checkerboard", square_m=square_m, low_kg_ha=low_kg_ha, high_kg_ha=high_kg_ha)
    if square_m <= 0:
        raise MapError(f"synthetic.checkerboard: square_m={square_m!r} must be positive")
    grid, x, y = _blank("checkerboard", bounds, crs, cell_size_m)
    parity = (np.floor(x / square_m).astype(np.int64) + np.floor(y / square_m).astype(np.int64)) % 2
    grid.rates_kg_ha[:] = np.where(parity == 0, low_kg_ha, high_kg_ha)
    return grid
