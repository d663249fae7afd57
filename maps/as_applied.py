"""As-applied maps: product actually put down, accumulated from swath strips onto a prescription's grid.

Each control tick the implement covers a strip: its width across, the distance travelled along, from
(x0, y0) to (x1, y1), carrying `mass_kg` of product. `AsApplied.add_strips` spreads each strip's mass
over the cells it covers, area-weighted.

Method (vectorized, no per-strip Python): the grid is divided into `subcells` x `subcells` sub-cells
(2 x 2 by default). Each strip is cut into ``n_along x n_across`` equal sub-rectangles no larger than
h = half a sub-cell on a side. Each sub-rectangle's mass and area are split between the sub-cells
that its axis-aligned bounding box overlaps, in proportion to the overlap (at most 2 x 2, since the
box is smaller than a sub-cell), with ``np.add.at``. A cell's applied mass is the sum over its
sub-cells; its coverage the mean over its sub-cells of min(1, swept area / sub-cell area).

Accuracy: the total is exact (every kilogram lands in a cell or in `outside_kg`). For strips
travelling along the grid axes the split is exact, whatever the strip length (ticks of a few cm
included). For oblique strips the bounding box smears each sub-rectangle by up to h across a cell
edge: measured per-cell errors are below 0.5 % at any heading with full coverage (tests). Coverage
is exact for axis-aligned swaths and within ~1.5 % per cell for oblique ones (the box smear moves
swept area into neighbours, and the clip at 1 drops the excess); where two passes partly overlap
inside one sub-cell it can be over-counted (the overlap counts twice before the clip), an error of
at most one sub-cell along the overlap's edge. A zero-length strip (standing still while applying)
puts its mass at its point and covers no area.

Passes: strips may carry the pass they belong to (a stretch of path between turns). Each pass is
accumulated on its own raster over the window of sub-cells it touches, then added to the rest,
which gives, per cell, how many passes put product on it (`pass_count`), the area more than one
pass swept (`overlap_fraction`) and the product beyond the first pass (`overlap_kg`), at a cost
that grows with the passes' area, not with the grid's.
"""

from __future__ import annotations

from dataclasses import dataclass

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
        Sub-cells per cell side of the accumulation raster (default 2); strips are sampled at half a
        sub-cell.
    """

    def __init__(self, grid: Grid, subcells: int = 2):
        if not isinstance(grid, Grid):
            raise MapError(f"AsApplied: grid must be a maps.Grid, got {type(grid).__name__}")
        if not (isinstance(subcells, int) and 1 <= subcells <= 32):
            raise MapError(f"AsApplied: subcells={subcells!r} must be an integer in 1..32")
        self.grid = grid
        self._cell_area_m2 = grid.cell_area_m2  # refuses lon/lat grids with a clear message
        self._subcells = subcells
        # Sub-cell raster with a one-sub-cell ring around it that collects everything off the grid
        # (indices are clipped into the ring: no masks in the hot loop). Real part: mass in kg;
        # imaginary part: swept area in CRS units^2, so one np.add.at updates both.
        self._shape = (grid.rows * subcells + 2, grid.cols * subcells + 2)
        self._acc = np.zeros(self._shape[0] * self._shape[1], dtype=np.complex128)
        self.total_kg = 0.0
        self.strips = 0
        # Pass accounting (see `add_strips`' pass_index). The open pass deposits into its own raster
        # (`_pass_acc`, made on first use, like `_acc`), over a window of sub-cells `_window`; when
        # it closes, that window is added to `_acc`, and to the capped swept-area sum (`_capped`,
        # per interior sub-cell) and the pass count (`_count`, per cell) of the closed passes.
        dx, dy = grid.cell_size
        self._sub_area = dx * dy / subcells**2  # CRS units^2, like the swept area
        self._pass = None
        self._pass_acc = None
        self._window = None  # [row_min, row_max, col_min, col_max] touched, ring coordinates
        self._capped = np.zeros((grid.rows * subcells, grid.cols * subcells))
        self._count = np.zeros((grid.rows, grid.cols), dtype=np.int64)
        self._target = self._acc  # where `_spread` deposits

    def _interior(self, part: np.ndarray) -> np.ndarray:
        """The grid's sub-cells of `part` (flat, ring included) as (rows, s, cols, s) blocks."""
        s = self._subcells
        inner = part.reshape(self._shape)[1:-1, 1:-1]
        return inner.reshape(self.grid.rows, s, self.grid.cols, s)

    def _all(self) -> np.ndarray:
        """The accumulator with the open pass's deposits (flat, ring included)."""
        return self._acc if self._pass is None else self._acc + self._pass_acc

    def _ring_sum(self, parts: np.ndarray) -> np.ndarray:
        """Sum over the ring of each row of `parts` (n, flat sub-cells): what fell off the grid. Summed
        directly, not as all less the interior, which would lose the small remainder to rounding."""
        full = parts.reshape(parts.shape[0], *self._shape)
        return full[:, [0, -1], :].sum(axis=(1, 2)) + full[:, 1:-1, [0, -1]].sum(axis=(1, 2))

    @property
    def applied_kg(self) -> np.ndarray:
        """Applied product per cell, kg, shape (rows, cols)."""
        return self._interior(self._all().real).sum(axis=(1, 3))

    @property
    def applied_kg_ha(self) -> np.ndarray:
        """Applied product per cell, kg/ha, shape (rows, cols)."""
        return self.applied_kg * (10_000.0 / self._cell_area_m2)

    @property
    def outside_kg(self) -> float:
        """Product that fell outside the grid, kg."""
        return float(self._ring_sum(self._all().real[None, :])[0])

    @property
    def coverage_fraction(self) -> np.ndarray:
        """Share of each cell's area that product was applied to, in [0, 1], shape (rows, cols)."""
        return np.minimum(self._interior(self._all().imag) / self._sub_area, 1.0).mean(axis=(1, 3))

    def as_grid(self) -> Grid:
        """The applied rates as a `Grid` on the prescription's geometry (cells never covered: NaN)."""
        rates = np.where(self.coverage_fraction > 0, self.applied_kg_ha, np.nan)
        g = self.grid
        return Grid(rates, g.transform, g.crs, product=g.product, source="as-applied", format="as-applied")

    def add_strips(self, x0, y0, x1, y1, width_m, mass_kg, pass_index=None) -> None:
        """Add strips of product.

        Parameters
        ----------
        x0, y0, x1, y1 : array_like, shape (k,)
            Start and end of each strip's centre line, in the grid's CRS (metres).
        width_m : float or array_like, shape (k,)
            Working width across the direction of travel, m.
        mass_kg : array_like, shape (k,)
            Product in each strip, kg (>= 0).
        pass_index : int or array_like of int, shape (k,), optional
            The pass each strip belongs to, for `pass_count` and the overlap figures. Strips of
            one pass come together, passes one after another (across calls too); a pass ends
            where the index changes.
        """
        x0, y0, x1, y1, width, mass = self._checked(x0, y0, x1, y1, width_m, mass_kg)
        if pass_index is None:
            self._target = self._acc
            self._add(x0, y0, x1, y1, width, mass)
            return
        passes = np.broadcast_to(np.asarray(pass_index, dtype=np.int64).ravel(), x0.shape)
        for lo, hi in _pass_runs(passes):
            self._begin_pass(int(passes[lo]))
            part = slice(lo, hi)
            self._add(x0[part], y0[part], x1[part], y1[part], width[part], mass[part])

    def _checked(self, x0, y0, x1, y1, width_m, mass_kg):
        """The strips as flat float arrays of one length, width in CRS units; `MapError` if one is bad."""
        x0, y0, x1, y1, width, mass = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64).ravel()
                                                          for v in (x0, y0, x1, y1, width_m, mass_kg)))
        bad = ~(np.isfinite(x0) & np.isfinite(y0) & np.isfinite(x1) & np.isfinite(y1))
        if bad.any():
            raise MapError(f"add_strips: strip {int(np.argmax(bad))} has a non-finite coordinate")
        for name, v in (("width_m", width), ("mass_kg", mass)):
            if not np.all(np.isfinite(v) & (v >= 0)):
                i = int(np.argmax(~(np.isfinite(v) & (v >= 0))))
                raise MapError(f"add_strips: {name}[{i}]={v[i]!r} must be finite and >= 0")
        return x0, y0, x1, y1, width / metres_per_unit(self.grid.crs), mass  # width like the coordinates

    def _add(self, x0, y0, x1, y1, width, mass) -> None:
        """Deposit checked strips (width in CRS units)."""
        for sel, nal, nac, dx, dy, length in self._patterns(x0, y0, x1, y1, width):
            self._deposit(x0[sel], y0[sel], dx, dy, length, width[sel], mass[sel], nal, nac)
        self.total_kg += float(mass.sum())
        self.strips += int(mass.size)

    def _patterns(self, x0, y0, x1, y1, width):
        """The strips in batches of one sampling pattern: (indices, n_al, n_ac, dx, dy, length) each."""
        dx, dy = x1 - x0, y1 - y0
        length = np.hypot(dx, dy)
        h = min(self.grid.cell_size) / (2 * self._subcells)
        n_al = np.maximum(1, np.ceil(length / h)).astype(np.int64)
        n_ac = np.maximum(1, np.ceil(width / h)).astype(np.int64)
        # Strips with the same sampling pattern are done together as (k, n_al, n_ac) arrays; a run
        # has one or a few patterns (short ticks: n_al = 1; one working width).
        key = n_al * (int(n_ac.max(initial=0)) + 1) + n_ac
        if key.size and (key == key[0]).all():
            patterns, group = key[:1], None  # the usual case: skip the sort
        else:
            patterns, group = np.unique(key, return_inverse=True)
        for g, k in enumerate(patterns):
            idx = np.arange(key.size) if group is None else np.flatnonzero(group == g)
            nal, nac = divmod(int(k), int(n_ac.max()) + 1)
            per_chunk = max(1, MAX_SAMPLES_PER_PASS // int(nal * nac))
            for lo in range(0, idx.size, per_chunk):
                sel = idx[lo:lo + per_chunk]
                yield sel, int(nal), int(nac), dx[sel], dy[sel], length[sel]

    # --- passes --------------------------------------------------------------------------------
    def _begin_pass(self, index: int) -> None:
        """Close the open pass if it is another, and deposit into pass `index`'s own raster."""
        if index != self._pass:
            if self._pass is not None:
                self._close_pass()
            if self._pass_acc is None:
                self._pass_acc = np.zeros_like(self._acc)
            self._pass = index
        self._target = self._pass_acc

    def _close_pass(self) -> None:
        capped, count, window = self._open_pass_terms()
        if window is not None:
            rows, cols = window
            self._capped[rows, cols] += capped
            self._count[rows.start // self._subcells: rows.stop // self._subcells,
                        cols.start // self._subcells: cols.stop // self._subcells] += count
            touched = self._touched()
            self._acc.reshape(self._shape)[touched] += self._pass_acc.reshape(self._shape)[touched]
            self._pass_acc.reshape(self._shape)[touched] = 0.0
        self._pass, self._window = None, None

    def _touched(self):
        r0, r1, c0, c1 = self._window
        return slice(r0, r1 + 1), slice(c0, c1 + 1)

    def _open_pass_terms(self):
        """The open pass's capped swept area per sub-cell and whether it put product on each cell,
        over the interior window (whole cells) it touched: (capped, count, (row slice, col slice))."""
        if self._pass is None or self._window is None:
            return None, None, None
        s = self._subcells
        r0, r1, c0, c1 = self._window
        # Interior sub-cells (ring coordinates less one), widened to whole cells.
        i0, i1 = max(r0 - 1, 0) // s * s, -(-min(r1, self._shape[0] - 2) // s) * s
        j0, j1 = max(c0 - 1, 0) // s * s, -(-min(c1, self._shape[1] - 2) // s) * s
        if i1 <= i0 or j1 <= j0:
            return None, None, None
        swept = self._pass_acc.reshape(self._shape)[1 + i0: 1 + i1, 1 + j0: 1 + j1].imag
        blocks = swept.reshape((i1 - i0) // s, s, (j1 - j0) // s, s).sum(axis=(1, 3))
        count = blocks >= 0.5 * self._sub_area * s * s
        return np.minimum(swept, self._sub_area), count, (slice(i0, i1), slice(j0, j1))

    def _with_open_pass(self):
        """Per interior sub-cell the sum over passes of each pass's swept area (capped at the
        sub-cell's area), and per cell the number of passes that swept at least half of it, the
        open pass included."""
        capped, count, window = self._open_pass_terms()
        if window is None:
            return self._capped, self._count
        rows, cols = window
        all_capped, all_count = self._capped.copy(), self._count.copy()
        all_capped[rows, cols] += capped
        s = self._subcells
        all_count[rows.start // s: rows.stop // s, cols.start // s: cols.stop // s] += count
        return all_capped, all_count

    @property
    def pass_count(self) -> np.ndarray:
        """Number of passes that put product on at least half of each cell, shape (rows, cols) (strips
        added without a pass index count for none)."""
        return self._with_open_pass()[1]

    @property
    def overlap_fraction(self) -> np.ndarray:
        """Share of each cell's area swept by more than one pass, in [0, 1], shape (rows, cols).

        Per sub-cell: the passes' swept areas (each capped at the sub-cell's area) summed, less the
        sub-cell's area; a lower bound of the area two passes share, exact when each covers whole
        sub-cells. A pass that sweeps the same ground twice (a turn) does not overlap itself.
        """
        capped = self._blocks(self._with_open_pass()[0])
        return (np.maximum(capped - self._sub_area, 0.0) / self._sub_area).mean(axis=(1, 3))

    @property
    def overlap_kg(self) -> np.ndarray:
        """Product applied beyond the first pass on each cell, kg, shape (rows, cols): per sub-cell,
        its product times the share of its passes' swept area that overlaps."""
        capped = self._blocks(self._with_open_pass()[0])
        extra = np.divide(np.maximum(capped - self._sub_area, 0.0), capped, out=np.zeros(capped.shape),
                          where=capped > 0)
        return (self._interior(self._all().real) * extra).sum(axis=(1, 3))

    def _blocks(self, sub: np.ndarray) -> np.ndarray:
        """Interior sub-cell values (rows * s, cols * s) as (rows, s, cols, s) blocks."""
        s = self._subcells
        return sub.reshape(self.grid.rows, s, self.grid.cols, s)

    def _deposit(self, x0, y0, dx, dy, length, width, mass, nal: int, nac: int):
        x, y, ext_x, ext_y, swept = _samples(x0, y0, dx, dy, length, width, nal, nac)
        # Strips carrying no product (sections off) sweep no coverage.
        load = (mass + 1j * np.where(mass > 0, swept, 0.0)) / (nal * nac)
        shape = x.shape
        self._spread(x.ravel(), y.ravel(), np.broadcast_to(ext_x[_PER_STRIP], shape).ravel(),
                     np.broadcast_to(ext_y[_PER_STRIP], shape).ravel(),
                     np.broadcast_to(load[_PER_STRIP], shape).ravel())

    def _corners(self, x, y, ext_x, ext_y):
        """The sub-cells (flat, ring coordinates) a sample's box overlaps and the shares that spill:
        (r0, r1, c0, c1, wr, wc), the rows already times the raster's row length."""
        g, s = self.grid, self._subcells
        rows, cols = self._shape
        kx, ky = g._inv_dx * s, g._inv_dy * s
        c0, c1, wc = _split((x - g._x0) * kx, 0.5 * kx * ext_x, cols)
        r0, r1, wr = _split((g._y0 - y) * ky, 0.5 * ky * ext_y, rows)
        if self._target is not self._acc:
            self._widen_window(r0, c0)
        r0 *= cols
        r1 *= cols
        return r0, r1, c0, c1, wr, wc

    def _spread(self, x, y, ext_x, ext_y, load):
        """Split each sample's load between the (at most 2 x 2) sub-cells its box overlaps."""
        r0, r1, c0, c1, wr, wc = self._corners(x, y, ext_x, ext_y)
        lc = load * (1.0 - wc)
        hc = load * wc
        acc = self._target
        np.add.at(acc, r0 + c0, lc * (1.0 - wr))
        np.add.at(acc, r0 + c1, hc * (1.0 - wr))
        np.add.at(acc, r1 + c0, lc * wr)
        np.add.at(acc, r1 + c1, hc * wr)

    def _widen_window(self, row, col) -> None:
        """Grow the open pass's window to the sub-cells of samples at `row`, `col` (ring coordinates)
        and their neighbours (a sample spills into one)."""
        if row.size == 0:
            return
        r0, r1 = int(row.min()) - 1, int(row.max()) + 1
        c0, c1 = int(col.min()) - 1, int(col.max()) + 1
        rows, cols = self._shape
        new = [max(r0, 0), min(r1, rows - 1), max(c0, 0), min(c1, cols - 1)]
        if self._window is not None:
            w = self._window
            new = [min(new[0], w[0]), max(new[1], w[1]), min(new[2], w[2]), max(new[3], w[3])]
        self._window = new


class StripMap:
    """Strips of one geometry as a linear map from their masses to the as-applied raster: what
    `AsApplied.add_strips` computes, for many mass columns at once (the same strips carrying the
    product of several controllers).

    The area weights (which sub-cells each strip's samples fall on, and in which shares) are
    computed once, as a sparse matrix from strips to sub-cells (scipy.sparse); `apply` maps mass
    columns through it. A strip sweeps coverage only in a column where it carries product, as in
    `AsApplied`; the swept-area figures (coverage, passes, overlap) are computed once per distinct
    pattern of strips carrying product, which the columns usually share. Equal to
    `AsApplied.add_strips` of each column to rounding (the sums are taken in another order).

    Parameters
    ----------
    grid : Grid
    x0, y0, x1, y1, width_m : array_like, shape (k,)
        As `AsApplied.add_strips`.
    subcells : int
        As `AsApplied`.
    pass_index : array_like of int, shape (k,), optional
        As `AsApplied.add_strips` (a pass is a run of strips of one index); with it, `apply` gives
        the pass figures too.
    """

    def __init__(self, grid: Grid, x0, y0, x1, y1, width_m, subcells: int = 2, pass_index=None):
        from scipy import sparse

        raster = AsApplied(grid, subcells)
        x0, y0, x1, y1, width, _ = raster._checked(x0, y0, x1, y1, width_m, 0.0)
        self._raster = raster
        self.swept = np.zeros(x0.size)  # swept area of each strip, CRS units^2
        cells, strips, weights = [], [], []
        for sel, nal, nac, dx, dy, length in raster._patterns(x0, y0, x1, y1, width):
            x, y, ext_x, ext_y, self.swept[sel] = _samples(x0[sel], y0[sel], dx, dy, length, width[sel],
                                                           nal, nac)
            shape = x.shape
            r0, r1, c0, c1, wr, wc = raster._corners(
                x.ravel(), y.ravel(), np.broadcast_to(ext_x[_PER_STRIP], shape).ravel(),
                np.broadcast_to(ext_y[_PER_STRIP], shape).ravel())
            strip = np.broadcast_to(sel[_PER_STRIP], shape).ravel()
            low, high = (1.0 - wc) / (nal * nac), wc / (nal * nac)
            for cell, w in ((r0 + c0, low * (1.0 - wr)), (r0 + c1, high * (1.0 - wr)),
                            (r1 + c0, low * wr), (r1 + c1, high * wr)):
                cells.append(cell)
                strips.append(strip)
                weights.append(w)
        self.weights = sparse.csr_matrix(
            (_joined(weights, float), (_joined(cells, np.int64), _joined(strips, np.int64))),
            shape=(raster._acc.size, x0.size))
        self._to_pass = None if pass_index is None else _runs_matrix(pass_index, x0.size)
        # The ring coordinates of each cell's s x s sub-cells, cell by cell (row-major cells), and the
        # cell of each sub-cell of the raster (-1: the ring), to recompute the cells a strip touches.
        s, rows, cols = subcells, grid.rows, grid.cols
        cell_r, cell_c, i, j = np.indices((rows, cols, s, s)).reshape(4, -1)
        ring_index = (cell_r * s + i + 1) * raster._shape[1] + cell_c * s + j + 1
        self._cell_subs = ring_index.reshape(rows * cols, s * s)
        self._sub_cell = np.full(raster._acc.size, -1, np.int64)
        self._sub_cell[self._cell_subs] = np.arange(rows * cols)[:, None]
        self._by_strip = None   # the weights by strip (CSC), made on first use
        self._base = None       # (pattern, its `_terms_at` over every cell): the first one seen
        self._sub_weights = None  # the weights of the sub-cells of cells, cell by cell (CSR), first use
        # The weights summed per cell and over the ring: applied and outside kg straight from masses.
        sub = np.flatnonzero(self._sub_cell >= 0)
        per_cell = sparse.csr_matrix((np.ones(sub.size), (self._sub_cell[sub], sub)),
                                     shape=(rows * cols, raster._acc.size))
        self._cell_weights = (per_cell @ self.weights).tocsr()
        self._ring_weights = np.asarray(self.weights[self._sub_cell < 0].sum(axis=0)).ravel()

    @property
    def strips(self) -> int:
        return self.swept.size

    def _checked(self, mass_kg) -> np.ndarray:
        mass = np.ascontiguousarray(mass_kg, dtype=float)   # once, not in each product below
        if mass.ndim != 2 or mass.shape[0] != self.strips or mass.shape[1] == 0:
            raise MapError(f"StripMap: mass_kg must have shape ({self.strips}, n >= 1), got {mass.shape}")
        if not np.all(np.isfinite(mass) & (mass >= 0)):
            raise MapError("StripMap: mass_kg must be finite and >= 0")
        return mass

    def apply(self, mass_kg) -> AppliedColumns:
        """The as-applied rasters of mass columns `mass_kg`, shape (k, n) (kg per strip, >= 0)."""

        mass = self._checked(mass_kg)
        raster, grid = self._raster, self._raster.grid
        shape = (grid.rows, grid.cols)
        terms, which, patched = self._patterns_of(mass)
        out = dict(applied_kg=np.asarray(self._cell_weights @ mass).T.reshape(-1, *shape),
                   coverage_fraction=np.stack([terms[u][0].reshape(shape) for u in which]),
                   outside_kg=self._ring_weights @ mass, cell_area_m2=raster._cell_area_m2)
        if self._to_pass is not None:
            # A sub-cell's product beyond the first pass is its share `extra` of the product on it.
            if self._sub_weights is None:
                self._sub_weights = self.weights[self._cell_subs.ravel()].tocsr()
            cells, s2 = self._cell_subs.shape
            per_sub = np.asarray(self._sub_weights @ mass).reshape(cells, s2, -1)   # kg
            overlap_kg = np.einsum("cs,csn->nc", self._base[1][3], per_sub)
            for u, at in enumerate(patched):   # a pattern's own terms differ at its patched cells only
                if at is not None and at.size:
                    cols = np.flatnonzero(which == u)
                    overlap_kg[np.ix_(cols, at)] = np.einsum("cs,csn->nc", terms[u][3][at],
                                                             per_sub[at][:, :, cols])
            out.update(pass_count=np.stack([terms[u][1].reshape(shape) for u in which]),
                       overlap_fraction=np.stack([terms[u][2].reshape(shape) for u in which]),
                       overlap_kg=overlap_kg.reshape(-1, *shape))
        return AppliedColumns(**out)

    def coverage_fraction(self, mass_kg) -> np.ndarray:
        """Only `apply`'s ``coverage_fraction``: (n, rows, cols), for mass columns (k, n)."""
        terms, which, _ = self._patterns_of(self._checked(mass_kg))
        grid = self._raster.grid
        return np.stack([terms[u][0].reshape(grid.rows, grid.cols) for u in which])

    def _patterns_of(self, mass: np.ndarray):
        """The swept-area terms (`_terms_at`, every cell) of each distinct pattern of strips carrying
        product in the columns of `mass`, each column's pattern, and each pattern's cells whose terms
        differ from the base's (None: the base's own terms). The base is the first pattern this map
        sees: its terms are computed over the whole grid (once); any other's are those with the cells
        recomputed that the strips where the two differ touch (the columns' patterns differ in a few
        strips, if at all)."""
        carries = mass.T > 0
        packed = np.packbits(carries, axis=1)   # a column's pattern as bytes, to look it up
        first: dict[bytes, int] = {}
        which = np.array([first.setdefault(row.tobytes(), len(first)) for row in packed], dtype=np.int64)
        patterns = carries[np.unique(which, return_index=True)[1]]
        if self._base is None:
            self._base = (patterns[0], self._terms_at(patterns[0], np.arange(self._cell_subs.shape[0])))
        base_pattern, base = self._base
        terms, patched_cells = [], []
        for pattern in patterns:
            differ = np.flatnonzero(pattern != base_pattern)
            if not differ.size:
                terms.append(base)
                patched_cells.append(None)
                continue
            if self._by_strip is None:
                self._by_strip = self.weights.tocsc()
            touched = self._by_strip[:, differ].indices
            cells = np.unique(self._sub_cell[touched])
            cells = cells[cells >= 0]
            patched = [None if t is None else t.copy() for t in base]
            for whole, part in zip(patched, self._terms_at(pattern, cells), strict=True):
                if whole is not None:
                    whole[cells] = part
            terms.append(patched)
            patched_cells.append(cells)
        return terms, which, patched_cells

    def _terms_at(self, carries: np.ndarray, cells: np.ndarray):
        """For strips carrying product where `carries`, at `cells` (flat cell indices): the coverage,
        and with passes the pass count and the overlap share, each shape (m,), and each sub-cell's
        share of its product beyond the first pass, shape (m, s * s) (`AsApplied`'s figures)."""
        from scipy import sparse

        raster = self._raster
        area, s2 = raster._sub_area, raster._subcells ** 2
        rows = self.weights[self._cell_subs[cells].ravel()]               # (m * s * s, strips)
        swept = self.swept * carries
        cover = np.minimum(np.asarray(rows @ swept).reshape(-1, s2) / area, 1.0).mean(axis=1)
        if self._to_pass is None:
            return cover, None, None, None
        per_pass = (rows @ sparse.diags(swept) @ self._to_pass).tocsr()  # (m * s * s, passes)
        m = len(cells)
        to_cell = sparse.csr_matrix((np.ones(m * s2), np.arange(m * s2), np.arange(0, m * s2 + 1, s2)),
                                    shape=(m, m * s2))
        per_cell = (to_cell @ per_pass).tocsr()
        per_cell.data = (per_cell.data >= 0.5 * area * s2).astype(float)
        count = np.asarray(per_cell.sum(axis=1)).ravel().astype(np.int64)
        per_pass.data = np.minimum(per_pass.data, area)
        capped = np.asarray(per_pass.sum(axis=1)).reshape(m, s2)
        overlap = (np.maximum(capped - area, 0.0) / area).mean(axis=1)
        extra = np.divide(np.maximum(capped - area, 0.0), capped, out=np.zeros(capped.shape),
                          where=capped > 0)
        return cover, count, overlap, extra


@dataclass(frozen=True)
class AppliedColumns:
    """As-applied rasters of n mass columns (`StripMap.apply`); each as the `AsApplied` property of the
    same name, with a leading axis of n; the pass figures None without passes."""

    applied_kg: np.ndarray          # (n, rows, cols), kg
    coverage_fraction: np.ndarray   # (n, rows, cols), in [0, 1]
    outside_kg: np.ndarray          # (n,), kg
    cell_area_m2: float
    pass_count: np.ndarray | None = None        # (n, rows, cols)
    overlap_fraction: np.ndarray | None = None  # (n, rows, cols), in [0, 1]
    overlap_kg: np.ndarray | None = None        # (n, rows, cols), kg

    @property
    def applied_kg_ha(self) -> np.ndarray:
        return self.applied_kg * (10_000.0 / self.cell_area_m2)


def _runs_matrix(pass_index, k: int):
    """Sparse (k, runs): strip i -> the run of one pass index it belongs to (a pass, `AsApplied`)."""
    from scipy import sparse

    passes = np.broadcast_to(np.asarray(pass_index, dtype=np.int64).ravel(), (k,))
    run = np.cumsum(np.concatenate(([0], passes[1:] != passes[:-1]))) if k else np.zeros(0, np.int64)
    return sparse.csr_matrix((np.ones(k), (np.arange(k), run)), shape=(k, int(run.max(initial=-1)) + 1))


def _pass_runs(passes: np.ndarray):
    """(start, stop) of each run of one pass index in `passes`."""
    cuts = np.concatenate(([0], np.flatnonzero(np.diff(passes)) + 1, [passes.size]))
    return [(int(lo), int(hi)) for lo, hi in zip(cuts[:-1], cuts[1:], strict=True) if hi > lo]


def _joined(parts: list, dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, dtype)


_PER_STRIP = (slice(None), None, None)  # per-strip values broadcast over (n_al, n_ac)


def _samples(x0, y0, dx, dy, length, width, nal: int, nac: int):
    """Centres (k, n_al, n_ac) of each strip's sub-rectangles, their axis-aligned extent (k,) and the
    strip's swept area (k,), CRS units."""
    col = _PER_STRIP
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(length > 0, 1.0 / length, 0.0)
    cos, sin = dx * inv, dy * inv
    # Sub-rectangle centres: u along in (0, 1), v across in (-1/2, 1/2); across = left normal.
    u = ((np.arange(nal) + 0.5) / nal)[None, :, None]
    v = ((np.arange(nac) + 0.5) / nac - 0.5)[None, None, :]
    x = x0[col] + u * dx[col] - v * (width * sin)[col]
    y = y0[col] + u * dy[col] + v * (width * cos)[col]
    # Axis-aligned extent of each sub-rectangle, for spreading it over the sub-cells it overlaps.
    a_al, a_ac = length / nal, width / nac
    ext_x = np.abs(cos) * a_al + np.abs(sin) * a_ac
    ext_y = np.abs(sin) * a_al + np.abs(cos) * a_ac
    return x, y, ext_x, ext_y, a_al * a_ac * nal * nac


def _split(f: np.ndarray, half: np.ndarray, n: int):
    """Where a box of half-width `half` (< 1/2) centred at `f` (in sub-cell units) falls.

    Returns the sub-cell holding `f`, the neighbour the box spills into, and the share that spills;
    indices are shifted by +1 and clipped to 0..n-1 for the ring (n = sub-cells + 2).
    """
    cell = np.floor(f)
    low = cell - (f - half)  # > 0: the box reaches into the sub-cell below
    high = (f + half) - (cell + 1.0)  # > 0: ... into the one above
    down = low > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        spill = np.where(down, low, np.maximum(high, 0.0)) / np.where(half > 0, 2.0 * half, 1.0)
    other = np.where(down, cell, cell + 2.0)  # cell - 1 or cell + 1, shifted by the ring
    cell += 1.0
    np.clip(cell, 0, n - 1, out=cell)
    np.clip(other, 0, n - 1, out=other)
    return cell.astype(np.int64), other.astype(np.int64), spill
