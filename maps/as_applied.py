"""As-applied maps: product actually put down, accumulated from swath strips onto a prescription's grid.

Each control tick the implement covers a strip: its width across, the distance travelled along, from
(x0, y0) to (x1, y1), carrying `mass_kg` of product. `AsApplied.add_strips` spreads each strip's mass
over the cells it covers, area-weighted.

Method (vectorized, no per-strip Python): each strip is cut into ``n_along x n_across`` equal
sub-rectangles no larger than `h` = cell / (2 * subcells) on a side, and each sub-rectangle's share
of the mass is put into the cell under its centre (midpoint rule); ``np.bincount`` sums all of them.
The same sample points mark a coverage raster `subcells` times finer than the grid in each direction.

Accuracy: the total is exact (every kilogram lands in a cell or in `outside_kg`); a cell's mass is
off by at most the mass of the sub-rectangles straddling its edge, i.e. a strip's mass is located to
within h / 2 (1/16 of a cell by default). Coverage is resolved to 1/subcells^2 of a cell (1/16).
A zero-length strip (the machine standing still while applying) puts its mass on the cells under
the points (x0, y0): its heading, and so its footprint, is unknown.
"""

from __future__ import annotations

import numpy as np

from common import MapError
from maps.crs import metres_per_unit
from maps.grid import Grid

MAX_SAMPLES_PER_PASS = 4_000_000  # ~200 MB of temporaries at most


class AsApplied:
    """Accumulates applied product on the grid of a prescription (a projected, metric CRS).

    Parameters
    ----------
    grid : Grid
        The prescription (only its geometry is used); its CRS must be projected.
    subcells : int
        Resolution of the coverage raster and sampling, per cell side (default 4).
    """

    def __init__(self, grid: Grid, subcells: int = 4):
        if not isinstance(grid, Grid):
            raise MapError(f"AsApplied: grid must be a maps.Grid, got {type(grid).__name__}")
        if not (isinstance(subcells, int) and 1 <= subcells <= 32):
            raise MapError(f"AsApplied: subcells={subcells!r} must be an integer in 1..32")
        self.grid = grid
        self._cell_area_m2 = grid.cell_area_m2  # refuses lon/lat grids with a clear message
        self._subcells = subcells
        self._mass = np.zeros(grid.rows * grid.cols)
        self._covered = np.zeros((grid.rows * subcells, grid.cols * subcells), dtype=bool)
        self.outside_kg = 0.0
        self.total_kg = 0.0
        self.strips = 0

    @property
    def applied_kg_ha(self) -> np.ndarray:
        """Applied product per cell, kg/ha, shape (rows, cols)."""
        return self._mass.reshape(self.grid.rows, self.grid.cols) * (10_000.0 / self._cell_area_m2)

    @property
    def applied_kg(self) -> np.ndarray:
        """Applied product per cell, kg, shape (rows, cols)."""
        return self._mass.reshape(self.grid.rows, self.grid.cols).copy()

    @property
    def coverage_fraction(self) -> np.ndarray:
        """Share of each cell's area covered at least once, in [0, 1], shape (rows, cols)."""
        s = self._subcells
        return self._covered.reshape(self.grid.rows, s, self.grid.cols, s).mean(axis=(1, 3))

    def as_grid(self) -> Grid:
        """The applied rates as a `Grid` on the prescription's geometry (cells never covered: NaN)."""
        rates = np.where(self.coverage_fraction > 0, self.applied_kg_ha, np.nan)
        g = self.grid
        return Grid(rates, g.transform, g.crs, product=g.product, source="as-applied", format="as-applied")

    def add_strips(self, x0, y0, x1, y1, width_m, mass_kg) -> None:
        """Add strips of product.

        Parameters
        ----------
        x0, y0, x1, y1 : array_like, shape (k,)
            Start and end of each strip's centre line, in the grid's CRS (metres).
        width_m : float or array_like, shape (k,)
            Working width across the direction of travel, m.
        mass_kg : array_like, shape (k,)
            Product in each strip, kg (>= 0).
        """
        x0, y0, x1, y1, width, mass = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64).ravel()
                                                          for v in (x0, y0, x1, y1, width_m, mass_kg)))
        bad = ~(np.isfinite(x0) & np.isfinite(y0) & np.isfinite(x1) & np.isfinite(y1))
        if bad.any():
            raise MapError(f"add_strips: strip {int(np.argmax(bad))} has a non-finite coordinate")
        for name, v in (("width_m", width), ("mass_kg", mass)):
            if not np.all(np.isfinite(v) & (v >= 0)):
                i = int(np.argmax(~(np.isfinite(v) & (v >= 0))))
                raise MapError(f"add_strips: {name}[{i}]={v[i]!r} must be finite and >= 0")
        width = width / metres_per_unit(self.grid.crs)  # in CRS units, like the coordinates
        dx, dy = x1 - x0, y1 - y0
        length = np.hypot(dx, dy)
        h = min(self.grid.cell_size) / (2 * self._subcells)
        n_al = np.maximum(1, np.ceil(length / h)).astype(np.int64)
        n_ac = np.maximum(1, np.ceil(width / h)).astype(np.int64)
        n = n_al * n_ac
        # Passes of whole strips with a bounded number of samples each.
        ends = np.cumsum(n)
        start = 0
        while start < n.size:
            base = ends[start - 1] if start else 0
            stop = max(start + 1, int(np.searchsorted(ends, base + MAX_SAMPLES_PER_PASS, side="right")))
            sl = slice(start, stop)
            self._deposit(x0[sl], y0[sl], dx[sl], dy[sl], length[sl], width[sl], mass[sl],
                          n_al[sl], n_ac[sl], n[sl])
            start = stop
        self.total_kg += float(mass.sum())
        self.strips += int(mass.size)

    def _deposit(self, x0, y0, dx, dy, length, width, mass, n_al, n_ac, n):
        total = int(n.sum())
        strip = np.repeat(np.arange(n.size), n)
        first = np.cumsum(n) - n
        j = np.arange(total) - first[strip]
        nac = n_ac[strip]
        # Sub-rectangle centres in strip coordinates: u along in (0, 1), v across in (-1/2, 1/2).
        u = ((j // nac) + 0.5) / n_al[strip]
        v = ((j % nac) + 0.5) / nac - 0.5
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(length > 0, 1.0 / length, 0.0)
        # Unit normal (left of travel) scaled by width: across offset = v * width * normal.
        nx = (-dy * inv * width)[strip]
        ny = (dx * inv * width)[strip]
        x = x0[strip] + u * dx[strip] + v * nx
        y = y0[strip] + u * dy[strip] + v * ny
        g, s = self.grid, self._subcells
        fc = (x - g._x0) * (g._inv_dx * s)
        fr = (g._y0 - y) * (g._inv_dy * s)
        inside = (fc >= 0) & (fc < g.cols * s) & (fr >= 0) & (fr < g.rows * s)
        fci = fc[inside].astype(np.int64)
        fri = fr[inside].astype(np.int64)
        share = (mass / n)[strip]
        self.outside_kg += float(share[~inside].sum())
        cell = (fri // s) * g.cols + (fci // s)
        self._mass += np.bincount(cell, weights=share[inside], minlength=self._mass.size)
        self._covered[fri, fci] = True

