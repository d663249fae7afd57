"""Strip geometry: where a section's strip lies, along the track (outlines) and across it (points), m.

Strips are outlined as polygons along the poses and filled into rasters by cell centre; a strip's
ground is read at points across each section. Offsets are lateral, left of the heading positive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.maps.rasterize import fill_rings
from vrsim.vehicle import Implement

_SAMPLES_PER_SECTION_MIN = 4  # a section's strip is read at least at this many points across
_RING_VERTEX_SPACING_M = 1.0  # landed strips are outlined with a vertex every metre (chord error
#                               below 2 cm on a 6 m turning radius) ...
_PIECE_VERTICES = 16  # ... in pieces of 15 m


@dataclass(frozen=True)
class Poses:
    """Poses along which strips are outlined: position (field CRS, m) and heading's cos and sin.

    The true ones outline the worked area, the sensed ones the terminal's coverage map.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    @classmethod
    def of(cls, track: dict) -> Poses:
        """The poses of a track's ``x_m``, ``y_m`` (m) and ``heading_rad`` (math convention)."""
        h = np.asarray(track["heading_rad"], float)
        return cls(np.asarray(track["x_m"], float), np.asarray(track["y_m"], float), np.cos(h), np.sin(h))

    def vertex_step(self, a: int, b: int) -> int:
        """Ticks between outline vertices about `_RING_VERTEX_SPACING_M` apart over poses [a, b]."""
        step_m = np.hypot(np.diff(self.x_m[a:b + 1]), np.diff(self.y_m[a:b + 1]))
        typical = float(np.median(step_m)) if step_m.size else 0.0
        return max(1, int(_RING_VERTEX_SPACING_M / typical)) if typical > 0 else 1

    def outlines(self, first: int, end: int, left_m: float, right_m: float, step: int) -> list:
        """Rings (vertex arrays (k, 2), m) outlining a strip swept over ticks [first, end).

        The strip lies between lateral offsets `left_m` and `right_m` (m, left of the heading
        positive) from pose `first` to pose `end` (the track's last at most), in pieces of
        `_PIECE_VERTICES` vertices so that a tight turn folds a ring over itself little.
        """
        xy, start = self.outline_runs([first], [end], [left_m], [right_m], step)
        return np.split(xy, start[1:-1])

    def outline_runs(self, first, end, left_m, right_m, step) -> tuple[np.ndarray, np.ndarray]:
        """The rings of `outlines` of many strips at once, concatenated: vertices (v, 2), m, and ring
        starts (r + 1,), ring k being vertices ``start[k]:start[k + 1]``.

        Strip j is swept over ticks [first[j], end[j]) between offsets left_m[j] and right_m[j] (m,
        arrays of shape (j,)), a vertex every `step` ticks (int, or one per strip) and at its last pose.
        """
        first, end = np.asarray(first, np.int64), np.asarray(end, np.int64)
        last = np.minimum(end, self.x_m.size - 1)
        step = np.broadcast_to(np.asarray(step, np.int64), first.shape)
        n = np.maximum(0, -(-(last - first) // step)) + 1   # vertices along each strip's edge
        # The vertices along every strip's left edges, then along its right ones.
        j, u = _enumerate(n)
        idx = np.where(u == n[j] - 1, last[j], first[j] + u * step[j])
        edges = np.concatenate([self._edge(idx, np.asarray(left_m, float)[j]),
                                self._edge(idx, np.asarray(right_m, float)[j])])
        # The rings: pieces of each strip, along its left edge and back along its right one.
        along = _PIECE_VERTICES - 1   # consecutive pieces share their end vertices
        strip, piece = _enumerate((np.maximum(n - 1, 1) + along - 1) // along)
        k0 = piece * along   # each ring's first vertex along its strip
        length = np.minimum(_PIECE_VERTICES, n[strip] - k0)   # its vertices along each edge
        ring, q = _enumerate(2 * length)
        half = length[ring]
        pos = np.where(q < half, q, idx.size + 2 * half - 1 - q)
        pos += (np.cumsum(n) - n)[strip][ring] + k0[ring]
        return edges[pos], np.concatenate(([0], np.cumsum(2 * length)))

    def _edge(self, idx, offset_m):
        # Left of the heading (cos h, sin h) is (-sin h, cos h).
        return np.stack([self.x_m[idx] - self.sin[idx] * offset_m,
                         self.y_m[idx] + self.cos[idx] * offset_m], 1)


def _enumerate(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Items 0 .. counts[i] - 1 of each group i, flat: (group of each item, its place in the group)."""
    group = np.repeat(np.arange(counts.size), counts)
    return group, np.arange(group.size) - np.repeat(np.cumsum(counts) - counts, counts)


def fill_outlines(out: np.ndarray, rings: list, west: float, north: float, size: float, value=True) -> None:
    """OR `value` into the cells of raster `out` whose centre lies inside any of `rings` (m).

    Each ring is its own polygon; the grid is north-up with corner (west, north), m, and square
    cells of `size` m.
    """
    if not rings:
        return
    xy = np.concatenate(rings)
    start = np.concatenate(([0], np.cumsum([len(r) for r in rings])))
    fill_rings(out, xy[:, 0], xy[:, 1], start, np.arange(len(rings)), west, north, size, value=value)


@dataclass(frozen=True)
class Strip:
    """Where a section's strip is read: points across each section, left to right, offsets in m."""

    offsets_m: np.ndarray  # (points,) left of the implement's centre
    starts: np.ndarray  # (sections,) first point of each section
    counts: np.ndarray  # (sections,) points per section
    edges_m: np.ndarray  # (sections, 2) left and right edge offsets of each section

    @classmethod
    def across(cls, implement: Implement, cell_m: float) -> Strip:
        """Points evenly across each section: one per `cell_m` (m) of its width, at least four."""
        widths, centres = implement.section_widths, implement.section_offsets_m
        counts = np.maximum(_SAMPLES_PER_SECTION_MIN, np.ceil(widths / cell_m)).astype(np.int64)
        sec = np.repeat(np.arange(widths.size), counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        offsets = centres[sec] + widths[sec] * (0.5 - (k + 0.5) / counts[sec])
        edges = np.stack([centres + widths / 2, centres - widths / 2], axis=1)
        return cls(offsets, np.cumsum(counts) - counts, counts, edges)

    def count(self, flags: np.ndarray) -> np.ndarray:
        """Per section, how many of its points are flagged: (points, m) 0/1 -> (m, sections). Other
        byte values are summed alike, in bytes where a section has at most 255 points: the caller keeps
        such sums below 256 (`CoverageRaster._read`: two flags a nibble apart, at most 15 points)."""
        # Points along the first axis: the sum over each section's points adds whole rows.
        if (self.counts == self.counts[0]).all():  # equal sections: one reshaped sum, 5x faster
            # Summed in bytes where a section's count fits one (6x faster than in int32).
            small = np.uint8 if self.counts[0] <= np.iinfo(np.uint8).max else np.int32
            counts = flags.reshape(self.counts.size, self.counts[0], -1).sum(axis=1, dtype=small)
            return counts.T.astype(np.int32)
        return np.add.reduceat(flags, self.starts, axis=0, dtype=np.int32).T
