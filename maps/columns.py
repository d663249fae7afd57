"""The deposition engine's batch mode: one footprint's geometry mapped to the as-applied raster once,
then applied to many mass columns at once (the same strips carrying several controllers' product:
sweeps' variants, the error split's reference meters).

The same algorithm as `maps.AsApplied` (the footprint's samples, `maps.subcells`' split and rules),
written as a sparse matrix from items to sub-cells (scipy.sparse) instead of deposited: equal to
`AsApplied.deposit` of each column to rounding (the sums are taken in another order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import MapError
from vrsim.maps.as_applied import checked_raster
from vrsim.maps.crs import metres_per_unit
from vrsim.maps.footprint import Footprint
from vrsim.maps.grid import Grid


class ColumnDeposit:
    """A footprint's items as a linear map from their masses to the as-applied raster: what
    `AsApplied.deposit` computes, for many mass columns at once.

    The weights (which sub-cells each item's samples fall on, and in which shares) are computed
    once, as a sparse matrix from items to sub-cells; `apply` maps mass columns through it. An item
    sweeps coverage only in a column where it carries product, as in `AsApplied`; the swept-area
    figures (coverage, passes, overlap) are computed once per distinct pattern of items carrying
    product, which the columns usually share.

    Parameters
    ----------
    grid : Grid
    footprint : Footprint
        Where the items put product (`maps.footprint`), in the grid's CRS.
    subcells : int
        As `AsApplied`.
    pass_index : array_like of int, shape (items,), optional
        As `AsApplied.deposit` (a pass is a run of items of one index); with it, `apply` gives the
        pass figures too.
    """

    def __init__(self, grid: Grid, footprint: Footprint, subcells: int = 2, pass_index=None):
        from scipy import sparse

        raster = checked_raster(grid, subcells, "ColumnDeposit")
        self._raster = raster
        self._cell_area_m2 = grid.cell_area_m2
        k = footprint.items
        self.swept = np.zeros(k)  # swept area of each item, CRS units^2
        cells, items, mass_w, area_w = [], [], [], []
        weighted = False
        for sm in footprint.samples(raster.step, metres_per_unit(grid.crs), slice(0, k)):
            self.swept[sm.items] = sm.swept
            r0, r1, c0, c1, wr, wc = raster.corners(sm.x.ravel(), sm.y.ravel(), sm.flat(sm.ext_x),
                                                    sm.flat(sm.ext_y))
            r0 *= raster.shape[1]
            r1 *= raster.shape[1]
            item = sm.flat(sm.items)
            n = sm.per_item
            low, high = (1.0 - wc) / n, wc / n  # equal shares of an item's area (and product)
            area_w += [low * (1.0 - wr), high * (1.0 - wr), low * wr, high * wr]
            if sm.weight is None:
                mass_w += area_w[-4:]
            else:
                weighted = True
                w = np.broadcast_to(sm.weight, sm.x.shape).ravel()
                m_low, m_high = (1.0 - wc) * w, wc * w
                mass_w += [m_low * (1.0 - wr), m_high * (1.0 - wr), m_low * wr, m_high * wr]
            cells += [r0 + c0, r0 + c1, r1 + c0, r1 + c1]
            items += [item] * 4
        where = (_joined(cells, np.int64), _joined(items, np.int64))
        # `area`: each item's swept area's shares; `weights`: its product's (the same matrix unless
        # the footprint weighs its samples).
        self.area = sparse.csr_matrix((_joined(area_w, float), where), shape=(raster.size, k))
        self.weights = (sparse.csr_matrix((_joined(mass_w, float), where), shape=(raster.size, k))
                        if weighted else self.area)
        self._to_pass = None if pass_index is None else _runs_matrix(pass_index, k)
        # The cells any item touches: elsewhere every swept-area term is 0 (no sub-cell swept).
        touched = raster.cell_of(np.flatnonzero(np.diff(self.area.indptr)))
        self._touched = np.unique(touched[touched >= 0])
        self._by_item = None    # the area weights by item (CSC), made on first use
        self._base = None       # (pattern, its `_terms_at` over every cell): the first one seen
        self._sub_weights = None  # the weights of the sub-cells of cells, cell by cell (CSR), first use
        # The weights summed per cell and over the ring (applied and outside kg straight from masses),
        # made on first use: what only `apply` reads.
        self._cell_weights = self._ring_weights = None

    @property
    def items(self) -> int:
        return self.swept.size

    def _checked(self, mass_kg) -> np.ndarray:
        mass = np.ascontiguousarray(mass_kg, dtype=float)   # once, not in each product below
        if mass.ndim != 2 or mass.shape[0] != self.items or mass.shape[1] == 0:
            raise MapError(f"ColumnDeposit: mass_kg must have shape ({self.items}, n >= 1), got {mass.shape}")
        if not np.all(np.isfinite(mass) & (mass >= 0)):
            raise MapError("ColumnDeposit: mass_kg must be finite and >= 0")
        return mass

    def apply(self, mass_kg) -> AppliedColumns:
        """The as-applied rasters of mass columns `mass_kg`, shape (k, n) (kg per item, >= 0)."""

        mass = self._checked(mass_kg)
        grid = self._raster.grid
        shape = (grid.rows, grid.cols)
        terms, which, patched = self._patterns_of(mass)
        if self._cell_weights is None:
            self._sum_weights()
        out = dict(applied_kg=np.asarray(self._cell_weights @ mass).T.reshape(-1, *shape),
                   coverage_fraction=np.stack([terms[u][0].reshape(shape) for u in which]),
                   outside_kg=self._ring_weights @ mass, cell_area_m2=self._cell_area_m2)
        if self._to_pass is not None:
            # A sub-cell's product beyond the first pass is its share `extra` of the product on it.
            if self._sub_weights is None:
                self._sub_weights = self.weights[self._raster.cell_subs().ravel()].tocsr()
            cells, s2 = grid.rows * grid.cols, self._raster.subcells ** 2
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

    def _sum_weights(self) -> None:
        """The weights summed per cell (CSR, cells x items) and over the ring (items,)."""
        from scipy import sparse

        raster = self._raster
        cell = raster.cell_of(np.arange(raster.size))
        sub = np.flatnonzero(cell >= 0)
        per_cell = sparse.csr_matrix((np.ones(sub.size), (cell[sub], sub)),
                                     shape=(raster.grid.rows * raster.grid.cols, raster.size))
        self._cell_weights = (per_cell @ self.weights).tocsr()
        self._ring_weights = np.asarray(self.weights[cell < 0].sum(axis=0)).ravel()

    def coverage_fraction(self, mass_kg) -> np.ndarray:
        """Only `apply`'s ``coverage_fraction``: (n, rows, cols), for mass columns (k, n)."""
        terms, which, _ = self._patterns_of(self._checked(mass_kg))
        grid = self._raster.grid
        return np.stack([terms[u][0].reshape(grid.rows, grid.cols) for u in which])

    def _patterns_of(self, mass: np.ndarray):
        """The swept-area terms (`_terms_at`, every cell) of each distinct pattern of items carrying
        product in the columns of `mass`, each column's pattern, and each pattern's cells whose terms
        differ from the base's (None: the base's own terms). The base is the first pattern this map
        sees: its terms are computed over the whole grid (once); any other's are those with the cells
        recomputed that the items where the two differ touch (the columns' patterns differ in a few
        items, if at all)."""
        carries = mass.T > 0
        packed = np.packbits(carries, axis=1)   # a column's pattern as bytes, to look it up
        first: dict[bytes, int] = {}
        which = np.array([first.setdefault(row.tobytes(), len(first)) for row in packed], dtype=np.int64)
        patterns = carries[np.unique(which, return_index=True)[1]]
        if self._base is None:
            self._base = (patterns[0], self._terms_everywhere(patterns[0]))
        base_pattern, base = self._base
        terms, patched_cells = [], []
        for pattern in patterns:
            differ = np.flatnonzero(pattern != base_pattern)
            if not differ.size:
                terms.append(base)
                patched_cells.append(None)
                continue
            if self._by_item is None:
                self._by_item = self.area.tocsc()
            cells = np.unique(self._raster.cell_of(self._by_item[:, differ].indices))
            cells = cells[cells >= 0]
            patched = [None if t is None else t.copy() for t in base]
            for whole, part in zip(patched, self._terms_at(pattern, cells), strict=True):
                if whole is not None:
                    whole[cells] = part
            terms.append(patched)
            patched_cells.append(cells)
        return terms, which, patched_cells

    def _terms_everywhere(self, carries: np.ndarray):
        """`_terms_at` every cell: worked out at the cells the items touch, 0 elsewhere."""
        raster = self._raster
        cells = raster.grid.rows * raster.grid.cols
        whole = []
        for part in self._terms_at(carries, self._touched):
            if part is not None:
                full = np.zeros((cells, *part.shape[1:]), part.dtype)
                full[self._touched] = part
                part = full
            whole.append(part)
        return tuple(whole)

    def _terms_at(self, carries: np.ndarray, cells: np.ndarray):
        """For items carrying product where `carries`, at `cells` (flat cell indices): the coverage,
        and with passes the pass count and the overlap share, each shape (m,), and each sub-cell's
        share of its product beyond the first pass, shape (m, s * s) (`AsApplied`'s figures)."""
        from scipy import sparse

        raster = self._raster
        area, s2 = raster.sub_area, raster.subcells ** 2
        rows = self.area[raster.cell_subs(cells).ravel()]                 # (m * s * s, items)
        swept = self.swept * carries
        cover = raster.covered(np.asarray(rows @ swept).reshape(-1, s2)).mean(axis=1)
        if self._to_pass is None:
            return cover, None, None, None
        per_pass = (rows @ sparse.diags(swept) @ self._to_pass).tocsr()  # (m * s * s, passes)
        m = len(cells)
        to_cell = sparse.csr_matrix((np.ones(m * s2), np.arange(m * s2), np.arange(0, m * s2 + 1, s2)),
                                    shape=(m, m * s2))
        per_cell = (to_cell @ per_pass).tocsr()
        per_cell.data = raster.pass_puts_on(per_cell.data).astype(float)
        count = np.asarray(per_cell.sum(axis=1)).ravel().astype(np.int64)
        per_pass.data = np.minimum(per_pass.data, area)
        capped = np.asarray(per_pass.sum(axis=1)).reshape(m, s2)
        return cover, count, raster.overlap_share(capped).mean(axis=1), raster.beyond_first(capped)


@dataclass(frozen=True)
class AppliedColumns:
    """As-applied rasters of n mass columns (`ColumnDeposit.apply`); each as the `AsApplied` property of the
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
    """Sparse (k, runs): item i -> the run of one pass index it belongs to (a pass, `AsApplied`)."""
    from scipy import sparse

    passes = np.broadcast_to(np.asarray(pass_index, dtype=np.int64).ravel(), (k,))
    run = np.cumsum(np.concatenate(([0], passes[1:] != passes[:-1]))) if k else np.zeros(0, np.int64)
    return sparse.csr_matrix((np.ones(k), (np.arange(k), run)), shape=(k, int(run.max(initial=-1)) + 1))


def _joined(parts: list, dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, dtype)
