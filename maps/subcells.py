"""The sub-cell raster of the deposition engine: where a sample's box falls, and the per-sub-cell rules
of coverage and passes that both of the engine's modes (`maps.AsApplied`, `maps.ColumnDeposit`) use.

The grid is divided into ``subcells x subcells`` sub-cells per cell, with a one-sub-cell ring around
it that collects everything off the grid (indices are clipped into the ring: no masks in the hot
loop). A sample (`maps.footprint.Samples`) is a box no larger than half a sub-cell on a side, so it
overlaps at most 2 x 2 sub-cells; its product and area are split between them in proportion to the
overlap. A cell's product is the sum over its sub-cells; its coverage the mean over its sub-cells of
min(1, swept area / sub-cell area).
"""

from __future__ import annotations

import numpy as np

from vrsim.maps.grid import Grid


class SubcellRaster:
    """The geometry of a grid's sub-cell raster, ring included (flat, row-major indices).

    Parameters
    ----------
    grid : Grid
        The prescription (its geometry only).
    subcells : int
        Sub-cells per cell side.
    """

    def __init__(self, grid: Grid, subcells: int):
        self.grid = grid
        self.subcells = subcells
        self.shape = (grid.rows * subcells + 2, grid.cols * subcells + 2)
        self.size = self.shape[0] * self.shape[1]
        dx, dy = grid.cell_size
        self.sub_area = dx * dy / subcells**2  # CRS units^2, like the swept area
        self.step = min(grid.cell_size) / (2 * subcells)  # the largest sample a footprint may give
        t = grid.transform  # the grid's own scalars (`Grid.lookup`'s), so the cells agree to the bit
        self._x0, self._y0 = t.c, t.f
        self._kx, self._ky = 1.0 / t.a * subcells, 1.0 / -t.e * subcells

    def corners(self, x, y, ext_x, ext_y):
        """The sub-cells a sample's box overlaps and the shares that spill: (r0, r1, c0, c1, wr, wc),
        ring coordinates; the box covers rows r0 (share 1 - wr) and r1 (wr), columns likewise."""
        rows, cols = self.shape
        kx, ky = self._kx, self._ky
        c0, c1, wc = _split((x - self._x0) * kx, 0.5 * kx * ext_x, cols)
        r0, r1, wr = _split((self._y0 - y) * ky, 0.5 * ky * ext_y, rows)
        return r0, r1, c0, c1, wr, wc

    def interior(self, part: np.ndarray) -> np.ndarray:
        """The grid's sub-cells of `part` (flat, ring included) as (rows, s, cols, s) blocks."""
        s = self.subcells
        inner = part.reshape(self.shape)[1:-1, 1:-1]
        return inner.reshape(self.grid.rows, s, self.grid.cols, s)

    def blocks(self, sub: np.ndarray) -> np.ndarray:
        """Interior sub-cell values (rows * s, cols * s) as (rows, s, cols, s) blocks."""
        s = self.subcells
        return sub.reshape(self.grid.rows, s, self.grid.cols, s)

    def ring_sum(self, parts: np.ndarray) -> np.ndarray:
        """Sum over the ring of each row of `parts` (n, flat sub-cells): what fell off the grid. Summed
        directly, not as all less the interior, which would lose the small remainder to rounding."""
        full = parts.reshape(parts.shape[0], *self.shape)
        return full[:, [0, -1], :].sum(axis=(1, 2)) + full[:, 1:-1, [0, -1]].sum(axis=(1, 2))

    def cell_subs(self, cells=None) -> np.ndarray:
        """The flat indices of the s x s sub-cells of `cells` (flat cell indices, row-major; default
        every cell), cell by cell, each cell's row by row: (cells, s * s)."""
        s, width = self.subcells, self.shape[1]
        cells = np.arange(self.grid.rows * self.grid.cols) if cells is None else np.asarray(cells, np.int64)
        cell_r, cell_c = np.divmod(cells, self.grid.cols)
        i, j = np.divmod(np.arange(s * s), s)
        return ((cell_r * s + 1) * width + cell_c * s + 1)[:, None] + (i * width + j)[None, :]

    def cell_of(self, subs) -> np.ndarray:
        """The flat cell index of each of the flat sub-cell indices `subs` (-1: the ring)."""
        s, (height, width) = self.subcells, self.shape
        r, c = np.divmod(np.asarray(subs, np.int64) - (width + 1), width)   # less the ring
        inside = (r >= 0) & (r < height - 2) & (c >= 0) & (c < width - 2)
        return np.where(inside, r // s * self.grid.cols + c // s, -1)

    def cell_sums(self, blocks: np.ndarray) -> np.ndarray:
        """Per cell the sum of its sub-cells' float values, from (rows, s, cols, s) `blocks`:
        ``blocks.sum(axis=(1, 3))`` to the bit, in its order (each row of a cell's sub-cells from the
        left, then the rows from the top), without numpy's loop call per row of s sub-cells (5 times
        slower at s = 2)."""
        s = blocks.shape[1]
        if s >= 8:   # numpy sums 8 or more in a row pairwise
            return blocks.sum(axis=(1, 3))
        rows = blocks[..., 0] + 0.0   # (rows, s, cols), from 0 as numpy starts (a sum of -0.0s is 0.0)
        for j in range(1, s):
            rows += blocks[..., j]
        total = rows[:, 0]
        for i in range(1, s):
            total = total + rows[:, i]
        return total

    def cell_means(self, blocks: np.ndarray) -> np.ndarray:
        """``blocks.mean(axis=(1, 3))`` to the bit (`cell_sums`, divided by the sub-cells' count)."""
        total = self.cell_sums(blocks)   # a new array: divided in place (a new one costs more)
        total /= blocks.shape[1] ** 2
        return total

    # --- the rules per sub-cell, shared by both modes ------------------------------------------
    # (Each works in the one new array it returns: a second one costs more than the arithmetic.)
    def covered(self, swept: np.ndarray) -> np.ndarray:
        """Share of each sub-cell swept, from its swept area (clipped at 1)."""
        share = swept / self.sub_area
        return np.minimum(share, 1.0, out=share)

    def pass_puts_on(self, swept_per_cell: np.ndarray) -> np.ndarray:
        """Whether a pass put product on a cell: it swept at least half of it (its sub-cells' sum)."""
        s = self.subcells
        return swept_per_cell >= 0.5 * self.sub_area * s * s

    def overlap_share(self, capped: np.ndarray) -> np.ndarray:
        """Share of each sub-cell swept by more than one pass, from the sum over passes of each one's
        swept area capped at the sub-cell's: a lower bound of the area two passes share."""
        share = capped - self.sub_area
        np.maximum(share, 0.0, out=share)
        share /= self.sub_area
        return share

    def beyond_first(self, capped: np.ndarray) -> np.ndarray:
        """Share of each sub-cell's product beyond the first pass (the overlapping share of its
        passes' swept area), from the same capped sum."""
        share = capped - self.sub_area
        np.maximum(share, 0.0, out=share)   # 0 where nothing is capped (capped <= 0)
        return np.divide(share, capped, out=share, where=capped > 0)


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
