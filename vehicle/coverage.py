"""Coverage path: headland passes, parallel swaths in serpentine order, and drivable turns.

The path is one continuous polyline in the field's metric CRS cut into `Segment`s. Headland passes
run around the inside of the boundary at (k + 1/2) working widths (convex corners rounded to the
turning radius); swaths are parallel lines one working width apart clipped to the area inside the
headlands; consecutive pieces are joined by the shortest forward-only turn (`vehicle.dubins`): a
U-turn when the spacing allows twice the turning radius, a bulb (omega) turn otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from vrsim.common.checks import check_number, check_positive
from vrsim.common.errors import VehicleError
from vrsim.vehicle.dubins import dubins_xy
from vrsim.vehicle.field import Field

KINDS = ("headland", "swath", "turn")
_MIN_PIECE_M = 1.0  # shorter swath pieces (tangent cuts at curved edges) are not worth a turn


@dataclass(frozen=True)
class Segment:
    """One drivable piece of the path.

    Attributes
    ----------
    kind : str
        "headland", "swath" or "turn".
    xy : ndarray, shape (k, 2)
        Vertices in metres (field CRS), k >= 2, in driving order.
    implement_on : bool
        True where product is applied (headland passes and swaths), False in turns.
    """

    kind: str
    xy: np.ndarray
    implement_on: bool

    @property
    def length_m(self) -> float:
        return float(np.hypot(*np.diff(self.xy, axis=0).T).sum())


@dataclass(eq=False)
class CoveragePath:
    """A planned coverage path and its arc-length lookup.

    Attributes
    ----------
    segments : list of Segment
    field : Field
    width_m, turn_radius_m : float
    inner : shapely Polygon or MultiPolygon
        The area inside the headland passes that the swaths cover, metres.
    swath_offsets_m : ndarray
        Lateral offset of each swath line (across the driving direction), m.
    heading_deg : float
        Compass bearing of the swaths (degrees clockwise from north).
    xy : ndarray, shape (n, 2)
        All vertices of the path, joins not repeated.
    s_m : ndarray, shape (n,)
        Arc length at each vertex, m; ``s_m[-1] == length_m``.
    seg_start_m, seg_length_m : ndarray, shape (len(segments),)
    """

    segments: list
    field: Field
    width_m: float
    turn_radius_m: float
    inner: object
    swath_offsets_m: np.ndarray
    heading_deg: float
    xy: np.ndarray = dc_field(init=False, repr=False)
    s_m: np.ndarray = dc_field(init=False, repr=False)
    seg_start_m: np.ndarray = dc_field(init=False, repr=False)
    seg_length_m: np.ndarray = dc_field(init=False, repr=False)

    def __post_init__(self):
        parts = [self.segments[0].xy] + [seg.xy[1:] for seg in self.segments[1:]]
        self.xy = np.concatenate(parts)
        self.s_m = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(self.xy, axis=0).T))])
        counts = np.array([len(seg.xy) - 1 for seg in self.segments])
        ends = np.cumsum(counts)
        self.seg_start_m = self.s_m[ends - counts]
        self.seg_length_m = self.s_m[ends] - self.seg_start_m
        d = np.diff(self.xy, axis=0)
        self._interval_heading = np.arctan2(d[:, 1], d[:, 0])
        self._seg_on = np.array([seg.implement_on for seg in self.segments])

    @property
    def length_m(self) -> float:
        """Total path length, m."""
        return float(self.s_m[-1])

    @property
    def worked_area_ha(self) -> float:
        """Area inside the headlands covered by the swaths' working width, ha."""
        return self.inner.intersection(self.swath_coverage()).area / 1e4

    def swath_coverage(self):
        """Union of the swaths' working strips (flat-ended, ``width_m`` wide), a shapely geometry."""
        strips = [LineString(seg.xy).buffer(self.width_m / 2, cap_style="flat")
                  for seg in self.segments if seg.kind == "swath"]
        return shapely.union_all(strips)

    def kinds(self) -> list:
        return [seg.kind for seg in self.segments]

    def segment_at(self, s_m):
        """Index of the segment holding arc length ``s_m`` (m, array or scalar)."""
        idx = np.searchsorted(self.seg_start_m, s_m, side="right") - 1
        return np.clip(idx, 0, len(self.segments) - 1)

    def locate(self, s_m):
        """Position, heading, segment and implement state at arc lengths ``s_m`` (vectorized).

        Parameters
        ----------
        s_m : array_like
            Arc length along the path, m (clipped to [0, length_m]).

        Returns
        -------
        x_m, y_m, heading_rad, segment_index, implement_on : ndarrays like ``s_m``
            ``heading_rad`` is the math convention: counter-clockwise from +x (east).
        """
        s = np.clip(np.asarray(s_m, dtype=float), 0.0, self.length_m)
        k = np.clip(np.searchsorted(self.s_m, s, side="right") - 1, 0, len(self.s_m) - 2)
        ds = self.s_m[k + 1] - self.s_m[k]
        f = np.divide(s - self.s_m[k], ds, out=np.zeros_like(s), where=ds > 0)[..., None]
        xy = self.xy[k] + f * (self.xy[k + 1] - self.xy[k])
        seg = self.segment_at(s)
        return xy[..., 0], xy[..., 1], self._interval_heading[k], seg, self._seg_on[seg]


def plan_coverage(field: Field, width_m: float, headland_passes: int = 1, heading_deg: float | None = None,
                  turn_radius_m: float = 6.0, step_m: float = 0.25) -> CoveragePath:
    """Plan headland passes and serpentine swaths over ``field``.

    Parameters
    ----------
    field : Field
    width_m : float
        Working width of the implement, m (> 0); also the swath spacing.
    headland_passes : int
        Number of passes around the boundary (>= 0).
    heading_deg : float, optional
        Swath (AB line) compass bearing, degrees clockwise from north. Default: the longest
        boundary edge.
    turn_radius_m : float
        Minimum turning radius of the tractor, m (> 0).
    step_m : float
        Sampling step of turn arcs, m.

    Raises
    ------
    VehicleError
        Bad width, passes or radius; a field too narrow for one swath or for the turning radius.
    """
    check_positive(width_m, "plan_coverage: width_m", VehicleError)
    check_positive(turn_radius_m, "plan_coverage: turn_radius_m", VehicleError)
    if not isinstance(headland_passes, (int, np.integer)) or isinstance(headland_passes, bool) \
            or headland_passes < 0:
        raise VehicleError(f"plan_coverage: headland_passes must be an integer >= 0, got {headland_passes!r}")
    if heading_deg is None:
        heading_deg = field.longest_edge_heading_deg()
    else:
        check_number(heading_deg, "plan_coverage: heading_deg", VehicleError)
    where = f"field {field.name!r}"
    rings = _headland_rings(field.polygon, width_m, headland_passes, turn_radius_m, where)
    inner = field.polygon.buffer(-headland_passes * width_m) if headland_passes else field.polygon
    if inner.is_empty:
        raise VehicleError(f"{where}: too narrow for one swath inside {headland_passes} headland "
                           f"pass(es) of width_m={width_m}")
    u = np.array([math.sin(math.radians(heading_deg)), math.cos(math.radians(heading_deg))])
    offsets, pieces = _swath_pieces(inner, u, width_m, where)
    pieces = _extend_to_strips(pieces, offsets, inner, field.polygon, u, width_m)
    start = None
    if rings:  # begin the swaths near where the last headland pass ends
        end = rings[-1][0]
        start = (float(end @ _perp(u)), float(end @ u))
    order = _serpentine(pieces, offsets, start)

    segments: list[Segment] = []
    for ring in rings:
        _append(segments, "headland", ring, step_m, turn_radius_m)
    for line, a, b in order:
        v = offsets[line]
        xy = np.array([a * u + v * _perp(u), b * u + v * _perp(u)])
        _append(segments, "swath", xy, step_m, turn_radius_m)
    return CoveragePath(segments, field, float(width_m), float(turn_radius_m), inner,
                        offsets, float(heading_deg) % 360.0)


def _perp(u):
    return np.array([-u[1], u[0]])


def _headland_rings(polygon: Polygon, width_m, passes, radius_m, where):
    """Closed rings (as (k, 2) arrays, first point repeated last) of each headland pass."""
    rings = []
    for k in range(passes):
        # Shrinking by offset + r and growing back by r rounds convex corners to the turning radius.
        core = polygon.buffer(-((k + 0.5) * width_m + radius_m), quad_segs=16)
        if core.is_empty:
            what = "turn_radius_m" if k == 0 else "headland_passes"
            value = radius_m if k == 0 else passes
            raise VehicleError(f"{where}: cannot hold {what}={value} (headland pass {k + 1} at "
                               f"width_m={width_m} with corners of radius {radius_m} m leaves no room)")
        pass_area = core.buffer(radius_m, quad_segs=16)
        for poly in getattr(pass_area, "geoms", [pass_area]):
            for ring in [poly.exterior, *poly.interiors]:
                rings.append(np.asarray(ring.coords))
    return rings


def _swath_pieces(inner, u, width_m, where):
    """Lateral offsets of the swath lines and their pieces inside ``inner``.

    Returns (offsets, pieces) with pieces a list of (line_index, u_start, u_end), u along ``u``.
    """
    p = _perp(u)
    coords = np.concatenate([np.asarray(r.coords) for poly in getattr(inner, "geoms", [inner])
                             for r in [poly.exterior, *poly.interiors]])
    along, across = coords @ u, coords @ p
    v0, v1 = across.min(), across.max()
    span = v1 - v0
    if span < width_m * (1 - 1e-9):
        raise VehicleError(f"{where}: too narrow for one swath: {span:.2f} m across inside the "
                           f"headlands, width_m={width_m}")
    n = math.ceil(span / width_m - 1e-9)
    # Full widths from one side; the last swath overlaps the one before it to reach the other side.
    offsets = v0 + width_m / 2 + width_m * np.arange(n, dtype=float)
    offsets[-1] = v1 - width_m / 2
    a0, a1 = along.min() - 1.0, along.max() + 1.0
    lines = [LineString([a0 * u + v * p, a1 * u + v * p]) for v in offsets]
    pieces = []
    for i, cut in enumerate(shapely.intersection(lines, inner)):
        for g in getattr(cut, "geoms", [cut]):
            if isinstance(g, LineString) and g.length >= _MIN_PIECE_M:
                s = np.asarray(g.coords) @ u
                pieces.append((i, float(s.min()), float(s.max())))
    if not pieces:
        raise VehicleError(f"{where}: too narrow for one swath of width_m={width_m}")
    return offsets, pieces


def _u_ranges(geoms, u):
    """(u_min, u_max) of each part of each geometry, as one list per geometry."""
    out = []
    for geom in geoms:
        parts = [g for g in getattr(geom, "geoms", [geom]) if not g.is_empty]
        out.append([(float((c := shapely.get_coordinates(g) @ u).min()), float(c.max())) for g in parts])
    return out


def _extend_to_strips(pieces, offsets, inner, boundary, u, width_m):
    """Lengthen swath pieces so the working strip, not only its centre line, reaches the edge of the
    area inside the headlands where that edge is slanted to the swaths.

    Each end grows to the end of the strip's part of ``inner`` that holds the piece, but by at most
    three working widths and never with the centre line leaving the field ``boundary``.
    """
    p = _perp(u)
    coords = shapely.get_coordinates(boundary)
    a0, a1 = (coords @ u).min() - 1.0, (coords @ u).max() + 1.0
    half = width_m / 2 * (1 - 1e-6)
    strips = [Polygon([a0 * u + (v - half) * p, a1 * u + (v - half) * p, a1 * u + (v + half) * p,
                       a0 * u + (v + half) * p]) for v in offsets]
    lines = [LineString([a0 * u + v * p, a1 * u + v * p]) for v in offsets]
    strip_parts = _u_ranges(shapely.intersection(strips, inner), u)
    field_parts = _u_ranges(shapely.intersection(lines, boundary), u)
    out = []
    for line, a, b in pieces:
        lo, hi = a - 3 * width_m, b + 3 * width_m
        for ranges in (strip_parts[line], field_parts[line]):
            for r0, r1 in ranges:
                if r0 <= a + 1e-6 and b - 1e-6 <= r1:
                    lo, hi = max(lo, r0), min(hi, r1)
                    break
        out.append((line, min(a, lo), max(b, hi)))
    return out


def _serpentine(pieces, offsets, start=None):
    """Order swath pieces into cells driven back and forth, cells visited nearest first.

    A cell is a run of pieces on consecutive lines that overlap one-to-one along the swath
    direction (a boustrophedon cell); non-convex fields split into several cells.
    """
    by_line: dict[int, list] = {}
    for piece in sorted(pieces):
        by_line.setdefault(piece[0], []).append(piece)
    cells, open_cells = [], {}  # open_cells: piece -> cell list whose last piece it is
    for line in sorted(by_line):
        prev = [q for q in open_cells if q[0] == line - 1]
        new_open = {}
        for piece in by_line[line]:
            over = [q for q in prev if _overlap(q, piece)]
            if len(over) == 1 and sum(_overlap(over[0], o) for o in by_line[line]) == 1:
                cell = open_cells[over[0]]
            else:
                cell = []
                cells.append(cell)
            cell.append(piece)
            new_open[piece] = cell
        open_cells = new_open
    order, pos = [], start
    remaining = list(cells)
    while remaining:
        # Enter the next cell at whichever of its four corners is nearest the current position.
        best = min(((_dist(pos, c, first, fwd, offsets), ci, first, fwd) for ci, c in enumerate(remaining)
                    for first in (True, False) for fwd in (True, False)))
        _, ci, first, fwd = best
        cell = remaining.pop(ci)
        seq = cell if first else cell[::-1]
        for j, (line, a, b) in enumerate(seq):
            forward = fwd == (j % 2 == 0)
            order.append((line, a, b) if forward else (line, b, a))
        line, a, b = order[-1]
        pos = (offsets[line], b)
    return order


def _overlap(p, q):
    return min(p[2], q[2]) - max(p[1], q[1]) > 0


def _dist(pos, cell, first, fwd, offsets):
    """Distance from ``pos`` (across, along) to where a cell would be entered."""
    line, a, b = cell[0] if first else cell[-1]
    if pos is None:
        return 0.0 if (first and fwd) else 1.0  # no position yet: the first cell, as planned
    return math.hypot(offsets[line] - pos[0], (a if fwd else b) - pos[1])


def _append(segments, kind, xy, step_m, radius_m):
    """Append ``xy`` as a segment, joined to the previous one by a turn (and rings rotated to start
    ahead of the previous end)."""
    xy = np.asarray(xy, dtype=float)
    if segments:
        end = segments[-1].xy
        h_end = math.atan2(*(end[-1] - end[-2])[::-1])
        if kind == "headland":
            ahead = end[-1] + 2.5 * radius_m * np.array([math.cos(h_end), math.sin(h_end)])
            xy = _ring_from(xy, ahead)
        h_start = math.atan2(*(xy[1] - xy[0])[::-1])
        turn = dubins_xy((*end[-1], h_end), (*xy[0], h_start), radius_m, step_m)
        if len(turn) >= 2:
            segments.append(Segment("turn", turn, False))
    if kind == "headland":  # a closed ring is two segments, so no SUMO edge starts and ends at one node
        half = len(xy) // 2
        segments.append(Segment(kind, xy[: half + 1], True))
        segments.append(Segment(kind, xy[half:], True))
    else:
        segments.append(Segment(kind, xy, True))


def _ring_from(ring: np.ndarray, point) -> np.ndarray:
    """The closed ring ``ring`` re-started at its point nearest ``point``."""
    line = LineString(ring)
    s0 = line.project(shapely.Point(point))
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ring, axis=0).T))])
    k = int(np.searchsorted(s, s0, side="right"))
    start = np.asarray(line.interpolate(s0).coords[0])
    body = np.concatenate([ring[k:-1], ring[:k]])
    out = np.concatenate([[start], body, [start]])
    keep = np.concatenate([[True], np.hypot(*np.diff(out, axis=0).T) > 1e-6])
    keep[-1] = True
    return out[keep]
