"""The coverage raster: the terminal's coverage map, where product has landed and where the field is.

Coverage switching reads each section's strip off it ahead of the implement (`CoverageRaster.wanted`)
and marks what landed where a pass ends (`CoverageRaster.mark`). North-up in the field's metric CRS,
square cells a fraction of a section wide (`coverage_cell_m`, m).
"""

from __future__ import annotations

import base64
import math
import zlib

import numpy as np
import shapely

from vrsim.maps.rasterize import fill_rings
from vrsim.services.sim.sections.strips import Poses, Strip
from vrsim.vehicle import Implement

# Bits of the coverage raster, a nibble apart: a section's codes summed count both at once (`_read`).
_TREATED, _OUTSIDE = np.uint8(1), np.uint8(16)
_NIBBLE = 15   # a section of at most this many points counts both flags in one sum
_CELLS_PER_SECTION = 8  # default coverage cell: the narrowest section / this
_MAX_COVERAGE_CELLS = 16_000_000  # 16 MB of coverage raster at most; coarser cells beyond
_MIN_COVERAGE_CELL_M = 0.05
_READ_POINTS = 65_536  # strip points read at once (`CoverageRaster.flagged`): work arrays in cache


def coverage_cell_m(implement: Implement, map_cell_m: float | None = None) -> float:
    """Default coverage-raster cell, m: an eighth of the narrowest section, no coarser than the map's."""
    cell = float(implement.section_widths.min()) / _CELLS_PER_SECTION
    if map_cell_m is not None:
        cell = min(cell, float(map_cell_m))
    return max(cell, _MIN_COVERAGE_CELL_M)


class CoverageRaster:
    """Where product has landed so far, and where the field is, on a north-up raster of `cell_m` m cells.

    One byte per cell: `_TREATED` once a landed strip covers the cell's centre, `_OUTSIDE` where the
    centre lies outside the field. Points beyond the raster read as the nearest edge cell, which
    lies outside the field (the raster has a margin).

    Parameters
    ----------
    field_polygon : shapely Polygon or MultiPolygon
        The field boundary in the metric CRS of the positions.
    cell_m : float
        Cell size, m; larger where the raster would exceed 16 million cells.
    margin_m : float
        Margin around the field's bounds, m.
    """

    def __init__(self, field_polygon, cell_m: float, margin_m: float):
        minx, miny, maxx, maxy = field_polygon.bounds
        margin = margin_m + 2 * cell_m
        area = (maxx - minx + 2 * margin) * (maxy - miny + 2 * margin)
        cell = max(cell_m, math.sqrt(area / _MAX_COVERAGE_CELLS))
        self.cell_m = cell
        self.west, self.north = minx - margin, maxy + margin
        self.cols = math.ceil((maxx + margin - self.west) / cell)
        self.rows = math.ceil((self.north - miny + margin) / cell)
        # The field's cells filled with the outside bit, then every cell's bit flipped (in place).
        self.state = np.zeros((self.rows, self.cols), np.uint8)
        fill_rings(self.state, *_polygon_rings(field_polygon), self.west, self.north, cell, value=_OUTSIDE)
        self.state ^= _OUTSIDE
        self._work: list[np.ndarray] | None = None  # `_read`'s work arrays

    def wanted(self, strip: Strip, x_m, y_m, cos, sin, treated_pct: float, outside_pct: float):
        """Whether each section's product is wanted on its strip: bool (m, sections).

        The strips lie across points (x_m, y_m) (m) heading (cos, sin), arrays of shape (m,);
        wanted is no more than `treated_pct` (%) of the strip on treated ground and no more than
        `outside_pct` (%) outside the field.
        """
        treated, outside = self.flagged(strip, x_m, y_m, cos, sin)
        counts = strip.counts
        return (treated * 100.0 <= treated_pct * counts) & (outside * 100.0 <= outside_pct * counts)

    def flagged(self, strip: Strip, x_m, y_m, cos, sin) -> tuple[np.ndarray, np.ndarray]:
        """How many of each section's strip points (`strip.counts`) lie on treated ground and how many
        outside the field: int (m, sections) each, for strips across points (x_m, y_m) (m) heading
        (cos, sin), arrays of shape (m,)."""
        # In cell units relative to the raster's corner, float32 (exact to a thousandth of a cell).
        inv = 1.0 / self.cell_m
        off = (strip.offsets_m * inv).astype(np.float32)[:, None]
        col = ((x_m - self.west) * inv).astype(np.float32)
        row = ((self.north - y_m) * inv).astype(np.float32)
        cos, sin = cos.astype(np.float32), sin.astype(np.float32)
        m, points = col.size, off.size
        treated, outside = (np.empty((m, strip.counts.size), np.int32) for _ in range(2))
        ticks = max(1, _READ_POINTS // points)
        for lo in range(0, m, ticks):
            part = slice(lo, lo + ticks)
            treated[part], outside[part] = self._read(strip, off, col[part], row[part], cos[part], sin[part])
        return treated, outside

    def _read(self, strip: Strip, off, col, row, cos, sin) -> tuple[np.ndarray, np.ndarray]:
        """`flagged` of a few ticks, in cell units (float32, (points, 1) and (k,)), in work arrays
        allocated once and small enough to stay in the cache (`_READ_POINTS`)."""
        n = off.size * col.size
        if self._work is None:
            self._work = [np.empty(_READ_POINTS, t) for t in (np.float32, np.float32, np.int32, np.int32,
                                                                 np.uint8, np.uint8)]
        fx, fy, cell, part, code, flags = (w[:n].reshape(off.size, -1) for w in self._work)
        np.subtract(col[None, :], np.multiply(sin[None, :], off, out=fx), out=fx)
        np.subtract(row[None, :], np.multiply(cos[None, :], off, out=fy), out=fy)
        # Points beyond the raster read its nearest edge cell. A pose a cell or more inside the raster
        # by the strip's half width has every point inside: clipping would change none (2 of the 11
        # passes over the points saved; the raster's margin keeps nearly every pose so).
        reach = float(np.abs(off).max(initial=0.0)) + 1.0
        for f, at, size in ((fx, col, self.cols), (fy, row, self.rows)):
            if not (at.size and at.min() >= reach and at.max() <= size - 1 - reach):
                np.clip(f, 0, size - 1, out=f)
        # At most _MAX_COVERAGE_CELLS: int32 cells (half the work of int64); truncated as astype does.
        np.copyto(cell, fy, casting="unsafe")
        cell *= self.cols
        np.copyto(part, fx, casting="unsafe")
        cell += part
        np.take(self.state.reshape(-1), cell, out=code, mode="clip")  # in the raster: clipping is moot
        if strip.counts.max() <= _NIBBLE:   # one sum: treated points in the low nibble, outside in the high
            both = strip.count(code)
            return both & _NIBBLE, both >> 4
        treated = strip.count(np.bitwise_and(code, _TREATED, out=flags))
        return treated, strip.count(np.right_shift(code, 4, out=flags))

    def treated(self) -> str:
        """The treated cells as plain data: the `_TREATED` bits packed, zlib-compressed, base64.

        A coverage map of millions of cells stays a few kilobytes; `_OUTSIDE` follows from the field.
        """
        bits = np.packbits((self.state & _TREATED).astype(bool).reshape(-1))
        return base64.b64encode(zlib.compress(bits.tobytes(), 6)).decode("ascii")

    def set_treated(self, packed: str) -> None:
        """Restore the treated cells from what `treated` returned."""
        bits = np.frombuffer(zlib.decompress(base64.b64decode(packed)), np.uint8)
        treated = np.unpackbits(bits, count=self.state.size).reshape(self.state.shape).astype(bool)
        self.state = (self.state & _OUTSIDE) | np.where(treated, _TREATED, np.uint8(0))

    def mark(self, strip: Strip, pose: Poses, a: int, landed: np.ndarray) -> None:
        """Record as treated the strips landed at poses a, a+1, ... (`landed`: bool (m, sections)).

        Each run of a section is outlined from its first pose to the pose after its last.
        """
        step = pose.vertex_step(a, a + landed.shape[0])
        # The runs of all sections at once, section by section: +1 where a run begins, -1 after it.
        edges = np.diff(landed.T.astype(np.int8), prepend=np.int8(0), append=np.int8(0), axis=1)
        section, first = np.nonzero(edges == 1)
        end = np.nonzero(edges == -1)[1]
        if not section.size:
            return
        left_m, right_m = strip.edges_m[section].T
        xy, start = pose.outline_runs(a + first, a + end, left_m, right_m, step)
        fill_rings(self.state, xy[:, 0], xy[:, 1], start, np.arange(start.size - 1), self.west, self.north,
                   self.cell_m, value=_TREATED)


def _polygon_rings(polygon):
    """Vertex arrays of a (multi)polygon's rings, exterior and holes of a part sharing an owner."""
    rings, owners = [], []
    for part, geom in enumerate(getattr(polygon, "geoms", [polygon])):
        for ring in [geom.exterior, *geom.interiors]:
            rings.append(shapely.get_coordinates(ring))
            owners.append(part)
    xy = np.concatenate(rings)
    start = np.concatenate(([0], np.cumsum([len(r) for r in rings])))
    return xy[:, 0], xy[:, 1], start, np.asarray(owners)
