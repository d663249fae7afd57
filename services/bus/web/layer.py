"""The live page's as-applied layer and the raster it is shown on: the rate samples deposited as they
arrive through the run's deposition engine (`maps.AsApplied`), on a `maps.Grid` of the view.

Pure: no zenoh, no HTTP; `services.bus.web.live.LiveView` holds a layer and paints its samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from affine import Affine

from vrsim.common import ServiceError
from vrsim.maps import AsApplied, Grid, Strips

MAX_VIEW_CELLS = 500_000  # a larger map is shown (and accumulated) on a coarser grid
LINE_M = 1e-3  # a rate sample is a line across the heading: a strip this long along it (m)
VIEW_CRS = ('ENGCRS["vrsim view",EDATUM["landing points"],CS[Cartesian,2],'  # `ViewGrid.as_grid`
            'AXIS["easting",east,LENGTHUNIT["metre",1]],AXIS["northing",north,LENGTHUNIT["metre",1]]]')


@dataclass(frozen=True)
class ViewGrid:
    """The raster the page shows, in the map's CRS: the map's own grid, or every ``stride``-th cell of
    it when the map has more than `MAX_VIEW_CELLS` cells. Row 0 is the north row."""

    west_m: float
    north_m: float
    cell_x_m: float
    cell_y_m: float
    rows: int
    cols: int
    stride: int = 1

    @classmethod
    def from_info(cls, info, max_cells: int = MAX_VIEW_CELLS) -> ViewGrid:
        """From a ``map/info`` reply (untrusted: every field used is checked)."""
        if not isinstance(info, dict):
            raise ServiceError(f"map/info: expected a JSON object, got {type(info).__name__}")
        bounds, cell = info.get("bounds"), info.get("cell_size")
        rows, cols = info.get("rows"), info.get("cols")
        if not (_numbers(bounds, 4) and _numbers(cell, 2) and min(cell) > 0):
            raise ServiceError(f"map/info: bounds {bounds!r} and cell_size {cell!r} must be 4 and 2 finite "
                               "numbers, cell sizes > 0")
        if not all(type(v) is int and v > 0 for v in (rows, cols)) or rows * cols > 10**10:
            raise ServiceError(f"map/info: rows {rows!r} and cols {cols!r} must be positive integers")
        stride = max(1, math.ceil(math.sqrt(rows * cols / max_cells)))
        return cls(float(bounds[0]), float(bounds[3]), cell[0] * stride, cell[1] * stride,
                   math.ceil(rows / stride), math.ceil(cols / stride), stride)

    @property
    def cells(self) -> int:
        return self.rows * self.cols

    def as_grid(self) -> Grid:
        """This raster as a `maps.Grid` (no rates) in the page's frame, metres east and north as the
        rate samples' landing points: what the deposition engine accumulates on."""
        transform = Affine(self.cell_x_m, 0.0, self.west_m, 0.0, -self.cell_y_m, self.north_m)
        return Grid(np.zeros((self.rows, self.cols)), transform, VIEW_CRS, source="live view")

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """x and y of every cell's centre, row-major, shape (rows * cols,)."""
        x, y = self.as_grid().cell_centres()
        return np.tile(x, self.rows), np.repeat(y, self.cols)

    def to_dict(self) -> dict:
        return {"west_m": self.west_m, "north_m": self.north_m, "cell_x_m": self.cell_x_m,
                "cell_y_m": self.cell_y_m, "rows": self.rows, "cols": self.cols, "stride": self.stride}


def _numbers(value, n: int) -> bool:
    return (isinstance(value, list) and len(value) == n
            and all(type(v) in (int, float) and math.isfinite(v) for v in value))


class AppliedLayer:
    """The live as-applied layer on a `ViewGrid`: per cell the mean applied rate (kg/ha) of the rate
    samples whose lines crossed it, each weighted by its line's length across the cell, and the frame
    in which it last changed.

    The lines go through the deposition engine as they arrive (`maps.AsApplied`, one sub-cell per
    cell: sampled every half cell) as `maps.Strips` a millimetre long across the heading, twice: their
    lengths (``line_m``, m per cell) and their lengths times their rates, whose ratio is the mean.
    """

    def __init__(self, grid: ViewGrid):
        self.grid = grid
        self._frame = grid.as_grid()
        self._length = AsApplied(self._frame, subcells=1)  # per cell: m of sample lines
        self._rated = AsApplied(self._frame, subcells=1)   # ... times their rates, m kg/ha
        self.line_m = np.zeros(grid.cells)
        self.mean_kg_ha = np.zeros(grid.cells)
        self.stamp = np.full(grid.cells, -1, dtype=np.int64)  # frame seq of the last change

    def paint(self, seq: int, x_m, y_m, heading_rad, width_m, offset_m, applied_kg_ha) -> int:
        """Add samples (arrays of one length); returns the number of cells touched.

        Each sample is a line across the heading, ``width_m`` long, centred ``offset_m`` to the left
        of (x, y). Samples with a non-finite or negative value, or no width, are left out (sections
        off, standstill, off the map).
        """
        x, y, h, w, off, rate = (np.asarray(a, dtype=np.float64) for a in
                                 (x_m, y_m, heading_rad, width_m, offset_m, applied_kg_ha))
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(h) & np.isfinite(off) & np.isfinite(rate) \
            & (rate >= 0) & np.isfinite(w) & (w > 0)
        if not ok.any():
            return 0
        x, y, h, w, off, rate = x[ok], y[ok], h[ok], w[ok], off[ok], rate[ok]
        along_x, along_y = np.cos(h), np.sin(h)  # a heading counter-clockwise from east
        cx, cy = x - along_y * off, y + along_x * off  # the line's centre, `off` to the left
        half = 0.5 * LINE_M
        lines = Strips(cx - half * along_x, cy - half * along_y, cx + half * along_x, cy + half * along_y, w)
        self._length.deposit(lines, w)
        self._rated.deposit(lines, w * rate)
        # Only the cells the lines can reach are read back (a frame's lines lie close together).
        half_w = 0.5 * w
        window = self._reach(np.concatenate([cx - along_y * half_w, cx + along_y * half_w]),
                             np.concatenate([cy - along_x * half_w, cy + along_x * half_w]))
        line_m = self._length.applied_kg_in(*window)
        shown = self.line_m.reshape(self.grid.rows, self.grid.cols)[window]
        changed = line_m != shown
        shown[changed] = line_m[changed]
        mean = self.mean_kg_ha.reshape(self.grid.rows, self.grid.cols)[window]
        mean[changed] = self._rated.applied_kg_in(*window)[changed] / line_m[changed]
        self.stamp.reshape(self.grid.rows, self.grid.cols)[window][changed] = seq
        return int(np.count_nonzero(changed))

    def _reach(self, x: np.ndarray, y: np.ndarray) -> tuple[slice, slice]:
        """The window of cells (rows, cols) around points, a cell beyond them (a sample's box spills
        into the next cell at most), found by `maps.Grid.lookup` of its corners clipped to the grid."""
        west, south, east, north = self._frame.bounds
        cell_x, cell_y = self._frame.cell_size
        xs = np.clip([x.min() - cell_x, x.max() + cell_x], west, np.nextafter(east, west))
        ys = np.clip([y.max() + cell_y, y.min() - cell_y], np.nextafter(south, north), north)
        corner = self._frame.lookup(xs, ys)
        return slice(corner.row[0], corner.row[1] + 1), slice(corner.col[0], corner.col[1] + 1)

    def since(self, seq: int) -> dict:
        """Cells changed after frame ``seq``: ``{"i": flat indices, "v": mean kg/ha}`` (-1: all)."""
        i = np.flatnonzero(self.stamp > seq)
        return {"i": i.tolist(), "v": np.round(self.mean_kg_ha[i], 2).tolist()}

    @property
    def painted(self) -> int:
        return int(np.count_nonzero(self.line_m))
