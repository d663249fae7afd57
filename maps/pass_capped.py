"""The passes' capped swept areas of an as-applied raster (`maps.AsApplied`), held sparse.

Per interior sub-cell the overlap figures read the sum over passes of each pass's swept area capped at
the sub-cell's area (`SubcellRaster.overlap_share`, `beyond_first`). Most sub-cells are swept by one
pass: their sum is that pass's capped area, which the raster itself holds (its swept area, only that
pass's). So only the sub-cells two or more passes swept keep a sum of their own (sorted flat indices
and sums), beside a pass count per sub-cell (0, 1, or 2 for more): 8 bytes a sub-cell become 1 and 16
per sub-cell where passes meet (a 534 ha map at 2 m cells: 7 MB and a few, not 55 MB). The sums are
those of a dense array, bit for bit: each adds the same capped areas in the same order.

Product deposited without a pass adds swept area no pass owns, so from the first such deposit the sums
are held dense (`to_dense`), as worked out until then.
"""

from __future__ import annotations

import numpy as np


class CappedSums:
    """The capped swept-area sums of the interior sub-cells, shape `shape`, each sub-cell of `area`."""

    def __init__(self, shape: tuple[int, int], area: float):
        self.shape, self.area = shape, area
        self.count = np.zeros(shape, dtype=np.uint8)   # passes that swept each sub-cell: 0, 1, 2 or more
        self.at = np.zeros(0, dtype=np.int64)          # flat indices of the sub-cells of 2 passes or more ...
        self.sums = np.zeros(0)                         # ... and their sums
        self.dense = None                               # the sums held dense (`to_dense`)
        self.passes = 0
        self._new = []   # the open pass's sub-cells of two passes, till `end_pass`

    def add_pass(self, rows: slice, cols: slice, before: np.ndarray, swept: np.ndarray) -> None:
        """Add a pass's swept areas `swept` over a window (`rows`, `cols`) of interior sub-cells (a pass
        may come in several windows, then `end_pass`); `before`: the raster's swept areas there before
        the pass is added to it."""
        area = self.area
        if self.dense is not None:
            self.dense[rows, cols] += np.minimum(swept, area)
            return
        hit = swept > 0
        count = self.count[rows, cols]
        width = self.shape[1]
        more = hit & (count >= 2)
        if more.any():
            r, c = np.nonzero(more)
            self.sums[np.searchsorted(self.at, (r + rows.start) * width + c + cols.start)] += \
                np.minimum(swept[more], area)
        second = hit & (count == 1)
        if second.any():   # the first pass's capped area (the raster's, before) and this one's
            r, c = np.nonzero(second)
            first = np.minimum(before[second], area)   # 0 + the first pass's capped area, as a dense sum
            at = (r + rows.start) * width + c + cols.start
            self._new.append((at, first + np.minimum(swept[second], area)))
        count[hit] = np.minimum(count[hit], 1) + 1

    def end_pass(self) -> None:
        """The pass's windows are all added: the sub-cells it made of two passes join the sums (a
        window's sub-cells are in no other window of the pass)."""
        self.passes += 1
        if not self._new:
            return
        at, sums = (np.concatenate(parts) for parts in zip(*self._new, strict=True))
        self._new = []
        order = np.argsort(at)
        at, sums = at[order], sums[order]
        where = np.searchsorted(self.at, at)
        self.at, self.sums = np.insert(self.at, where, at), np.insert(self.sums, where, sums)

    def band(self, rows: slice, swept: np.ndarray) -> np.ndarray:
        """The sums of the sub-cell rows `rows` (a new array, (rows, width)); `swept`: the raster's swept
        areas of those rows."""
        if self.dense is not None:
            return self.dense[rows].copy()
        out = np.where(self.count[rows] == 1, np.minimum(swept, self.area), 0.0)
        width = self.shape[1]
        lo, hi = np.searchsorted(self.at, (rows.start * width, rows.stop * width))
        out.ravel()[self.at[lo:hi] - rows.start * width] = self.sums[lo:hi]
        return out

    def to_dense(self, swept: np.ndarray) -> None:
        """Hold the sums dense from now on (product is about to be deposited without a pass); `swept`:
        the raster's swept areas of every interior sub-cell (read only if a pass was added)."""
        if self.dense is not None:
            return
        self.dense = self.band(slice(0, self.shape[0]), swept) if self.passes else np.zeros(self.shape)
        self.count, self.at, self.sums = None, None, None
