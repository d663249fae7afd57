"""Section control: which sections of the implement apply product, tick by tick.

Three ways of switching, chosen by ``[implement] section_control`` (a registry, `SWITCHING`):

- ``"coverage"``, as terminals do it: a section switches off when more than
  ``section_overlap_pct`` of its strip would land on ground already treated, or more than
  ``boundary_overlap_pct`` outside the field, and on again over untreated ground in the field.
  It decides ahead by its own latency plus the delivery delay (see `command`), predicting where
  it will be by dead reckoning from the sensed position, speed and heading as the control core
  does, and its gate follows the command after ``section_on_delay_s`` / ``section_off_delay_s``
  (see `gate`). Product is only wanted where the path is a working stretch (``implement_on`` at
  the pose where it would land: the terminal knows the planned path). At constant speed on
  straight lines the prediction is exact and latency costs nothing; where speed or heading
  change within the look-ahead (turns, speed variation) longer latencies leave more skips and
  overlap, as the terminals' manuals warn.
- ``"boundary"``: the behaviour before coverage control: a section applies while the implement is
  on and its centre, at the control core's predicted landing point, lies inside the field; no
  section latency.
- ``"off"``: all sections apply while the implement is on.

The time base: ``actual[t, s]`` says whether the gate of section s is open during tick t, i.e.
whether product metered in tick t passes it; that product lands on the true path
``delivery_delay_s`` later. ``commanded[t, s]`` is the terminal's command at tick t.

How coverage switching stays vectorized. Where a section's product is wanted depends only on
where product landed before, and within one pass (a stretch of working path between turns) a
section's strip never lands on its own earlier strip, except where the path turns back on
itself. So the track is cut into passes (`pass_index`: runs of ``implement_on``, cut again
wherever the heading has turned by half a circle, so a closing headland loop or a spiral is
several passes), and pass by pass: (1) for every decision whose product would land in the pass,
the share of each section's strip on treated ground and outside the field is read off a fine
coverage raster (`CoverageRaster`) holding everything earlier passes landed; (2) commands and
gate states follow by shifts and running maxima, no loop over ticks; (3) the strips the pass
actually landed are rasterized (scan lines) into the coverage raster. Approximations: ground a
pass treated itself counts as treated only for later passes, so within one pass the inner
sections of a turn tighter than half the working width keep applying where they pivot; the
coverage a decision sees is that of all earlier passes, not of the ticks just before it in
the same pass; and at a cut inside a working stretch the tick or two at the cut read the
previous pass's last strip at raster resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from maps.rasterize import fill_rings
from vehicle import Implement
from vehicle.implement import SECTION_CONTROL_MODES

TREATED, OUTSIDE = np.uint8(1), np.uint8(2)  # bits of the coverage raster
SAMPLES_PER_SECTION_MIN = 4  # a section's strip is read at least at this many points across
CELLS_PER_SECTION = 8  # default coverage cell: the narrowest section / this
MAX_COVERAGE_CELLS = 16_000_000  # 16 MB of coverage raster at most; coarser cells beyond
MIN_COVERAGE_CELL_M = 0.05
RING_VERTEX_SPACING_M = 1.0  # landed strips are outlined with a vertex every metre (chord error
#                              below 2 cm on a 6 m turning radius) ...
PIECE_VERTICES = 16  # ... in pieces of 15 m


@dataclass(frozen=True)
class SectionStates:
    """Per-tick section states of a run.

    Attributes
    ----------
    commanded : ndarray of bool, shape (n, sections)
        The terminal's command at each tick.
    actual : ndarray of bool, shape (n, sections)
        Whether the section's gate is open during the tick: product metered in tick t passes it
        and lands ``delivery_delay_s`` later on the section's own strip.
    widths_m, offsets_m : ndarray, shape (sections,)
        Width of each section and its centre's offset left of the implement's centre, m, left to right.
    pass_index : ndarray of int, shape (n,)
        The pass each tick's pose belongs to (-1 in turns); see `pass_index`.
    """

    commanded: np.ndarray
    actual: np.ndarray
    widths_m: np.ndarray
    offsets_m: np.ndarray
    pass_index: np.ndarray

    @property
    def width_on_m(self) -> np.ndarray:
        """Working width whose gates are open at each tick, m, shape (n,): the width the meter's
        target is computed for."""
        return self.actual @ self.widths_m

    @property
    def count_on(self) -> np.ndarray:
        """Number of sections applying at each tick, shape (n,)."""
        return self.actual.sum(axis=1)


def switch_sections(track: dict, implement: Implement, field_polygon, map_cell_m: float | None = None,
                    measured=None) -> SectionStates:
    """Section states over a whole run, by the implement's ``section_control``.

    Parameters
    ----------
    track : dict of ndarray, shape (n,)
        The true track: ``time_s`` (evenly spaced), ``x_m``, ``y_m`` (field CRS, metres),
        ``heading_rad`` (math convention), ``speed_m_s``, ``implement_on`` (bool: the path is a
        working stretch). Product lands on it.
    implement : vehicle.Implement
    field_polygon : shapely Polygon or MultiPolygon
        The field boundary in the track's CRS.
    map_cell_m : float, optional
        The prescription's cell size; the coverage raster is at least this fine.
    measured : (x_m, y_m, speed_m_s), optional
        What the terminal knows (GNSS position, sensed ground speed), arrays of shape (n,); it
        predicts where product will land from them and the heading by dead reckoning, as the
        control core does. Default: the true ones.
    """
    mode = implement.section_control
    n = len(track["time_s"])
    passes = pass_index(track["heading_rad"], track["implement_on"])
    if n == 0:
        empty = np.zeros((0, implement.sections), bool)
        return SectionStates(empty, empty, implement.section_widths, implement.section_offsets_m, passes)
    if measured is None:
        measured = (track["x_m"], track["y_m"], track["speed_m_s"])
    sensed = _Sensed.of(track, measured)
    commanded, actual = SWITCHING[mode](track, implement, field_polygon, map_cell_m, sensed, passes)
    return SectionStates(commanded, actual, implement.section_widths, implement.section_offsets_m, passes)


# --- the three ways of switching ----------------------------------------------------------------
def _all_on(track, implement, polygon, map_cell_m, sensed, passes):
    on = np.repeat(np.asarray(track["implement_on"], bool)[:, None], implement.sections, axis=1)
    return on, on


def _boundary(track, implement, polygon, map_cell_m, sensed, passes):
    lx, ly = sensed.ahead(implement.delivery_delay_s)
    on = implement.sections_on(polygon, lx, ly, track["heading_rad"], track["implement_on"])
    return on, on


def _coverage(track, implement, polygon, map_cell_m, sensed, passes):
    time_s = np.asarray(track["time_s"], float)
    n, sections = time_s.size, implement.sections
    period_s = _period_s(time_s)
    lag = _Lags.of(implement, period_s)
    raster = CoverageRaster(polygon, coverage_cell_m(implement, map_cell_m), margin_m=implement.width_m)
    strip = _Strip.across(implement, raster.cell_m)
    # The strip a tick's product covers is read at its middle, half a tick's travel further on.
    ahead_on = sensed.ahead(implement.delivery_delay_s + implement.section_on_delay_s + period_s / 2)
    ahead_off = sensed.ahead(implement.delivery_delay_s + implement.section_off_delay_s + period_s / 2)
    wanted_on, wanted_off = np.zeros((n, sections), bool), np.zeros((n, sections), bool)
    commanded = np.zeros((n, sections), bool)
    limits = (implement.section_overlap_pct, implement.boundary_overlap_pct)
    pose = Poses.of(track)
    for a, b in pass_bounds(passes):
        # The decisions whose product would land in this pass, on the true timeline.
        for wanted, (x, y), k in ((wanted_on, ahead_on, lag.on), (wanted_off, ahead_off, lag.off)):
            lo, hi = max(0, a - lag.delivery - k), max(0, b - lag.delivery - k)
            wanted[lo:hi] = raster.wanted(strip, x[lo:hi], y[lo:hi], sensed.cos[lo:hi], sensed.sin[lo:hi],
                                          *limits)
        landed = _landed_in_pass(wanted_on, wanted_off, commanded, lag, a, b,
                                 continues=b < n and passes[b] >= 0)
        raster.mark(strip, pose, a, landed)
    commanded = command(wanted_on, wanted_off, lag.on_first, np.zeros(sections, bool))
    return commanded, gate(commanded, lag.on, lag.off)


SWITCHING = {"coverage": _coverage, "boundary": _boundary, "off": _all_on}
assert set(SWITCHING) == set(SECTION_CONTROL_MODES)


# --- passes ----------------------------------------------------------------------------------------
def pass_index(heading_rad, implement_on) -> np.ndarray:
    """Pass of each tick: runs of ``implement_on`` numbered in order, a run cut again each time its
    heading has turned by half a circle since the piece began (-1 where the implement is off).

    A piece turning less than half a circle cannot lay its strip on its own earlier strip
    (except where the inner end of the implement pivots in a tight turn); the cut is greedy, so
    heading noise around a multiple of 180 degrees does not cut a straight stretch into many.
    """
    on = np.asarray(implement_on, bool)
    heading = np.unwrap(np.asarray(heading_rad, float)) if on.size else np.zeros(0)
    starts = []
    for a, b in runs_of(on):
        cut = a
        while cut < b:
            starts.append(cut)
            turned = np.abs(heading[cut:b] - heading[cut]) >= math.pi
            cut = cut + int(np.argmax(turned)) if turned.any() else b
    begin = np.zeros(on.size, np.int64)
    begin[starts] = 1
    out = np.cumsum(begin) - 1
    out[~on] = -1
    return out


def pass_bounds(passes) -> list[tuple[int, int]]:
    """(first tick, end tick) of each pass numbered in `passes`, in order."""
    passes = np.asarray(passes)
    change = np.flatnonzero(np.diff(passes) != 0) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [passes.size]))
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if passes[a] >= 0] \
        if passes.size else []


def runs_of(on: np.ndarray) -> list[tuple[int, int]]:
    """(first, end) of each run of True in boolean `on`."""
    edges = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [on.size]))
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if on.size and on[a]]


# --- latency: commands and gates -------------------------------------------------------------------
@dataclass(frozen=True)
class _Lags:
    """The delays in ticks: delivery (meter to ground), section on and off (command to gate)."""

    delivery: int
    on: int
    off: int

    @classmethod
    def of(cls, implement: Implement, period_s: float) -> _Lags:
        return cls(round(implement.delivery_delay_s / period_s),
                   round(implement.section_on_delay_s / period_s),
                   round(implement.section_off_delay_s / period_s))

    @property
    def on_first(self) -> bool:
        return self.on >= self.off

    @property
    def longest(self) -> int:
        return max(self.on, self.off)

    def decided_until(self, b: int) -> tuple[int, int]:
        """The first command tick whose on (off) look-ahead lands beyond pose `b`."""
        return max(0, b - self.delivery - self.on), max(0, b - self.delivery - self.off)


def _rows(a, lo, hi, end, continues):
    """Rows [lo, hi) of `a`; rows from `end` on are row ``end - 1`` (`continues`) or False."""
    out = np.zeros((max(hi - lo, 0), a.shape[1]), bool)
    take_hi = min(hi, end)
    if take_hi > lo:
        out[: take_hi - lo] = a[lo:take_hi]
    if continues and hi > end and end > 0:
        out[max(end - lo, 0):] = a[end - 1]
    return out


def command(wanted_on, wanted_off, on_first: bool, before) -> np.ndarray:
    """The terminal's command per tick from the two look-aheads; shape (m, sections).

    ``wanted_on[t]``: product is wanted where it would start landing if the section were commanded
    on at t; ``wanted_off[t]``: ... where it would stop landing if commanded off at t. When both
    agree the command follows them. When only the longer look-ahead wants product, the section
    switches (or stays) on; when only the shorter one does, it keeps its state (on: product still
    lands on wanted ground until it could stop; off: starting now would land on unwanted ground).
    The result: product starts and stops landing where wanted starts and stops (as far as the
    look-aheads predicted it), except
    that a gap shorter than the two delays' difference is bridged (overlap) and an island that
    short is skipped: the section cannot stop and restart, or start and stop, in time.

    ``before`` (sections,) is the command before the first tick.
    """
    decided = wanted_on | ~wanted_off
    value = wanted_on if on_first else wanted_off
    last = np.where(decided, np.arange(decided.shape[0], dtype=np.int32)[:, None], np.int32(-1))
    np.maximum.accumulate(last, axis=0, out=last)
    held = np.take_along_axis(value, np.maximum(last, 0), axis=0)
    return np.where(last >= 0, held, np.asarray(before, bool)[None, :])


def gate(commanded, on_ticks: int, off_ticks: int) -> np.ndarray:
    """Gate state per tick: each command takes effect `on_ticks` (switching on) or `off_ticks`
    (switching off) after it is given, and the gate follows the most recent command that has
    taken effect, so an on command cancelled before it took effect never opens the gate.
    All gates are closed before the first tick; shape as `commanded`."""
    m = commanded.shape[0]
    t = np.arange(m, dtype=np.int32)[:, None]
    arrived = np.full(commanded.shape, -1, np.int32)
    if on_ticks < m:
        src = commanded[: m - on_ticks]
        arrived[on_ticks:] = np.where(src, t[: m - on_ticks], -1)
    if off_ticks < m:
        src = ~commanded[: m - off_ticks]
        arrived[off_ticks:] = np.maximum(arrived[off_ticks:], np.where(src, t[: m - off_ticks], -1))
    np.maximum.accumulate(arrived, axis=0, out=arrived)
    return np.where(arrived >= 0, np.take_along_axis(commanded, np.maximum(arrived, 0), axis=0), False)


def _landed_in_pass(wanted_on, wanted_off, commanded, lag: _Lags, a: int, b: int,
                    continues: bool) -> np.ndarray:
    """Which sections' product lands at the poses [a, b) of one pass, shape (b - a, sections).

    Commands are worked out over a window reaching back far enough that every gate state it needs
    is decided inside it; the commands before it are final (their look-aheads land before the
    pass). Look-aheads landing beyond the pass are not decided yet: taken as the last decided one
    if the work `continues` into the next pass, else as not wanted. `commanded` is updated in
    place over the window.
    """
    sections = wanted_on.shape[1]
    lo = max(0, a - lag.delivery - lag.longest)
    hi = max(lo, b - lag.delivery)
    end_on, end_off = lag.decided_until(b)
    before = commanded[lo - 1] if lo > 0 else np.zeros(sections, bool)
    window = command(_rows(wanted_on, lo, hi, end_on, continues),
                     _rows(wanted_off, lo, hi, end_off, continues), lag.on_first, before)
    commanded[lo:hi] = window
    gates = gate(window, lag.on, lag.off)
    # Product landing at pose p left the meter at p - delivery.
    landed = np.zeros((b - a, sections), bool)
    first = a - lag.delivery
    src_lo = max(first, lo)
    landed[src_lo - first:] = gates[src_lo - lo: hi - lo]
    return landed


# --- geometry ----------------------------------------------------------------------------------------
def coverage_cell_m(implement: Implement, map_cell_m: float | None = None) -> float:
    """Default coverage-raster cell: an eighth of the narrowest section, no coarser than the map."""
    cell = float(implement.section_widths.min()) / CELLS_PER_SECTION
    if map_cell_m is not None:
        cell = min(cell, float(map_cell_m))
    return max(cell, MIN_COVERAGE_CELL_M)


@dataclass(frozen=True)
class _Sensed:
    """The pose and speed the terminal knows, and its dead-reckoned look-ahead."""

    x_m: np.ndarray
    y_m: np.ndarray
    speed_m_s: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    @classmethod
    def of(cls, track: dict, measured) -> _Sensed:
        x, y, v = (np.asarray(a, float) for a in measured)
        h = np.asarray(track["heading_rad"], float)
        return cls(x, y, v, np.cos(h), np.sin(h))

    def ahead(self, delay_s: float):
        """Where the implement will be `delay_s` later, straight ahead at the sensed speed: (x, y).
        The same arithmetic as the control core's landing point, so boundary mode matches it."""
        lead_m = self.speed_m_s * delay_s
        return self.x_m + lead_m * self.cos, self.y_m + lead_m * self.sin


def _period_s(time_s: np.ndarray) -> float:
    return float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0


@dataclass(frozen=True)
class Poses:
    """The true poses, along which landed strips are outlined."""

    x_m: np.ndarray
    y_m: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    @classmethod
    def of(cls, track: dict) -> Poses:
        h = np.asarray(track["heading_rad"], float)
        return cls(np.asarray(track["x_m"], float), np.asarray(track["y_m"], float), np.cos(h), np.sin(h))

    def vertex_step(self, a: int, b: int) -> int:
        """Ticks between outline vertices about `RING_VERTEX_SPACING_M` apart over poses [a, b]."""
        step_m = np.hypot(np.diff(self.x_m[a:b + 1]), np.diff(self.y_m[a:b + 1]))
        typical = float(np.median(step_m)) if step_m.size else 0.0
        return max(1, int(RING_VERTEX_SPACING_M / typical)) if typical > 0 else 1

    def outlines(self, first: int, end: int, left_m: float, right_m: float, step: int) -> list:
        """Rings (vertex arrays (k, 2)) outlining the strip between lateral offsets `left_m` and
        `right_m` (left of the heading positive) swept over ticks [first, end), i.e. from pose
        `first` to pose `end` (the track's last at most), in pieces of `PIECE_VERTICES` vertices so
        that a tight turn folds a ring over itself little."""
        last = min(end, self.x_m.size - 1)
        idx = np.append(np.arange(first, last, step), last)
        left, right = self._edge(idx, left_m), self._edge(idx, right_m)
        return [np.concatenate([left[k:k + PIECE_VERTICES], right[k:k + PIECE_VERTICES][::-1]])
                for k in range(0, max(idx.size - 1, 1), PIECE_VERTICES - 1)]

    def _edge(self, idx, offset_m):
        # Left of the heading (cos h, sin h) is (-sin h, cos h).
        return np.stack([self.x_m[idx] - self.sin[idx] * offset_m,
                         self.y_m[idx] + self.cos[idx] * offset_m], 1)


def fill_outlines(out: np.ndarray, rings: list, west: float, north: float, size: float, value=True) -> None:
    """OR `value` into the cells of raster `out` whose centre lies inside any of `rings` (each its
    own polygon), on a north-up grid with corner (west, north) and square cells of `size`."""
    if not rings:
        return
    xy = np.concatenate(rings)
    start = np.concatenate(([0], np.cumsum([len(r) for r in rings])))
    fill_rings(out, xy[:, 0], xy[:, 1], start, np.arange(len(rings)), west, north, size, value=value)


@dataclass(frozen=True)
class _Strip:
    """Where a section's strip is read: points across each section, left to right."""

    offsets_m: np.ndarray  # (points,) left of the implement's centre
    starts: np.ndarray  # (sections,) first point of each section
    counts: np.ndarray  # (sections,) points per section
    edges_m: np.ndarray  # (sections, 2) left and right edge offsets of each section

    @classmethod
    def across(cls, implement: Implement, cell_m: float) -> _Strip:
        widths, centres = implement.section_widths, implement.section_offsets_m
        counts = np.maximum(SAMPLES_PER_SECTION_MIN, np.ceil(widths / cell_m)).astype(np.int64)
        sec = np.repeat(np.arange(widths.size), counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        offsets = centres[sec] + widths[sec] * (0.5 - (k + 0.5) / counts[sec])
        edges = np.stack([centres + widths / 2, centres - widths / 2], axis=1)
        return cls(offsets, np.cumsum(counts) - counts, counts, edges)

    def count(self, flags: np.ndarray) -> np.ndarray:
        """Per section, how many of its points are flagged: (points, m) 0/1 -> (m, sections)."""
        # Points along the first axis: the sum over each section's points adds whole rows.
        return np.add.reduceat(flags, self.starts, axis=0, dtype=np.int32).T


class CoverageRaster:
    """Where product has landed so far, and where the field is, on a fine north-up raster.

    One byte per cell: `TREATED` once a landed strip covers the cell's centre, `OUTSIDE` where the
    centre lies outside the field. Points beyond the raster read as the nearest edge cell, which
    lies outside the field (the raster has a margin).
    """

    def __init__(self, field_polygon, cell_m: float, margin_m: float):
        minx, miny, maxx, maxy = field_polygon.bounds
        margin = margin_m + 2 * cell_m
        area = (maxx - minx + 2 * margin) * (maxy - miny + 2 * margin)
        cell = max(cell_m, math.sqrt(area / MAX_COVERAGE_CELLS))
        self.cell_m = cell
        self.west, self.north = minx - margin, maxy + margin
        self.cols = math.ceil((maxx + margin - self.west) / cell)
        self.rows = math.ceil((self.north - miny + margin) / cell)
        inside = np.zeros((self.rows, self.cols), bool)
        fill_rings(inside, *_polygon_rings(field_polygon), self.west, self.north, cell)
        self.state = np.where(inside, np.uint8(0), OUTSIDE)

    def wanted(self, strip: _Strip, x_m, y_m, cos, sin, treated_pct: float, outside_pct: float):
        """Whether each section's product is wanted on its strip across points (x_m, y_m) heading
        (cos, sin), arrays of shape (m,): no more than `treated_pct` of the strip on treated ground
        and no more than `outside_pct` outside the field; shape (m, sections)."""
        # In cell units relative to the raster's corner, float32 (exact to a thousandth of a cell),
        # shape (points, m).
        inv = 1.0 / self.cell_m
        off = (strip.offsets_m * inv).astype(np.float32)[:, None]
        col = ((x_m - self.west) * inv).astype(np.float32)[None, :] - sin.astype(np.float32)[None, :] * off
        row = ((self.north - y_m) * inv).astype(np.float32)[None, :] - cos.astype(np.float32)[None, :] * off
        np.clip(col, 0, self.cols - 1, out=col)
        np.clip(row, 0, self.rows - 1, out=row)
        cell = row.astype(np.int64)
        cell *= self.cols
        cell += col.astype(np.int64)
        code = self.state.reshape(-1)[cell]
        treated, outside = strip.count(code & TREATED), strip.count(code >> 1)
        counts = strip.counts
        return (treated * 100.0 <= treated_pct * counts) & (outside * 100.0 <= outside_pct * counts)

    def mark(self, strip: _Strip, pose: Poses, a: int, landed: np.ndarray) -> None:
        """Record as treated the strips landed at poses a, a+1, ... (`landed`, shape (m, sections)):
        each run of a section is outlined from its first pose to the pose after its last."""
        rings = []
        step = pose.vertex_step(a, a + landed.shape[0])
        for s in range(landed.shape[1]):
            left, right = strip.edges_m[s]
            for r0, r1 in runs_of(landed[:, s]):
                rings += pose.outlines(a + r0, a + r1, left, right, step)
        fill_outlines(self.state, rings, self.west, self.north, self.cell_m, value=TREATED)


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
