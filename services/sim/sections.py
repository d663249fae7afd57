"""Section control: which sections of the implement apply product, tick by tick.

Three ways of switching, chosen by ``[implement] section_control`` (a registry, `SWITCHING`):

- ``"coverage"``, as terminals do it: a section switches off when more than
  ``section_overlap_pct`` of its strip would land on ground already treated, or more than
  ``boundary_overlap_pct`` outside the field, or beyond the working stretch of the planned path
  (in a turn), and on again over untreated ground in the field. It decides ahead by its own
  latency plus the delivery delay (see `command`): where its strip will be is dead-reckoned from
  the sensed position, speed and heading as the control core does, and whether the path works
  there is read off the planned path at the distance travelled by then (the terminal follows the
  plan; its position along the plan is taken as the true one). The gate follows the command
  after ``section_on_delay_s`` / ``section_off_delay_s`` (see `gate`). At constant speed on
  straight lines the prediction is exact and latency costs nothing; where speed or heading change
  within the look-ahead (turns, speed variation) longer latencies leave more skips and overlap, as
  the terminals' manuals warn.
- ``"boundary"``: the behaviour before coverage control: a section applies while the implement is
  on and its centre, at the control core's predicted landing point, lies inside the field; no
  section latency.
- ``"off"``: all sections apply while the implement is on.

The time base: ``actual[t, s]`` says whether the gate of section s is open during tick t, i.e.
whether product metered in tick t passes it; that product lands ``delivery_delay_s`` later.
``commanded[t, s]`` is the terminal's command at tick t.

Causal, so it can run batch by batch. `SectionSwitch.step` takes the next ticks and carries
everything over (the coverage raster, the last commands, the gates' state, the open pass), so
stepping a track in batches of any size gives exactly the states of one step over the whole
track: `vrsim run` steps once, the Zenoh controller service once per lockstep batch.

How coverage switching stays vectorized. The coverage raster (`CoverageRaster`) is the terminal's
coverage map: it records where product landed, at the sensed positions, pass by pass. A pass is a
run of ``implement_on`` cut again wherever the heading has turned by half a circle (`PassTracker`:
a closing headland loop or a spiral is several passes); within a pass a section's strip never
lands on its own earlier strip (except where the path turns back on itself), so the raster needs
updating only where a pass ends: there, everything that landed since the previous pass ended (the
turn before it included) is rasterized (scan lines). Between two pass ends the raster is fixed, so
the decisions of all ticks between them are read off it at once and their commands and gates
follow by shifts and running maxima, no loop over ticks. Approximations: ground a pass treated
itself counts as treated only once it ends, so within one pass the inner sections of a turn
tighter than half the working width keep applying where they pivot, and a decision looking
across the end of a pass (within the look-ahead of a cut inside a working stretch) does not see
that pass's own strips yet.
"""

from __future__ import annotations

import base64
import math
import zlib
from dataclasses import dataclass

import numpy as np
import shapely

from maps.rasterize import fill_rings
from vehicle import CoveragePath, Implement
from vehicle.implement import SECTION_CONTROL_MODES

TREATED, OUTSIDE = np.uint8(1), np.uint8(2)  # bits of the coverage raster
SAMPLES_PER_SECTION_MIN = 4  # a section's strip is read at least at this many points across
CELLS_PER_SECTION = 8  # default coverage cell: the narrowest section / this
MAX_COVERAGE_CELLS = 16_000_000  # 16 MB of coverage raster at most; coarser cells beyond
MIN_COVERAGE_CELL_M = 0.05
RING_VERTEX_SPACING_M = 1.0  # landed strips are outlined with a vertex every metre (chord error
#                              below 2 cm on a 6 m turning radius) ...
PIECE_VERTICES = 16  # ... in pieces of 15 m
MAX_WANTED_TICKS = 20_000  # decisions read off the raster in chunks of this many ticks (memory)


@dataclass(frozen=True)
class SectionStates:
    """Per-tick section states of a run (or of one batch of ticks).

    Attributes
    ----------
    actual : ndarray of bool, shape (n, sections)
        Whether the section's gate is open during the tick: product metered in tick t passes it
        and lands ``delivery_delay_s`` later on the section's own strip.
    widths_m, offsets_m : ndarray, shape (sections,)
        Width of each section and its centre's offset left of the implement's centre, m, left to right.
    pass_index : ndarray of int, shape (n,)
        The pass each tick's pose belongs to (-1 in turns); see `pass_index`.
    commanded : ndarray of bool, shape (n, sections), or None
        The terminal's command at each tick; None where only the gates are known (a run's records
        rebuilt by the monitor).
    """

    actual: np.ndarray
    widths_m: np.ndarray
    offsets_m: np.ndarray
    pass_index: np.ndarray
    commanded: np.ndarray | None = None

    @property
    def width_on_m(self) -> np.ndarray:
        """Working width whose gates are open at each tick, m, shape (n,): the width the meter's
        target is computed for."""
        return self.actual @ self.widths_m

    @property
    def count_on(self) -> np.ndarray:
        """Number of sections applying at each tick, shape (n,)."""
        return self.actual.sum(axis=1)


class SectionSwitch:
    """Section states tick by tick, by the implement's ``section_control``, carried across `step` calls.

    Parameters
    ----------
    implement : vehicle.Implement
    field_polygon : shapely Polygon or MultiPolygon
        The field boundary in the metric CRS of the positions.
    path : vehicle.CoveragePath, optional
        The planned path (coverage control reads off it where the path works; required there).
    period_s : float
        Control period (one tick), s.
    map_cell_m : float, optional
        The prescription's cell size; the coverage raster is at least this fine.
    """

    def __init__(self, implement: Implement, field_polygon, path: CoveragePath | None = None,
                 period_s: float = 0.05, map_cell_m: float | None = None):
        self.implement = implement
        self.passes = PassTracker()
        self.engine = SWITCHING[implement.section_control](implement, field_polygon, path, period_s,
                                                           map_cell_m)
        self.tick = 0

    def step(self, x_m, y_m, heading_rad, speed_m_s, implement_on, s_m=None) -> SectionStates:
        """The states of the next ticks.

        Parameters
        ----------
        x_m, y_m, speed_m_s : array_like, shape (m,)
            What the terminal knows: the GNSS position (field CRS, m) and the sensed ground speed.
        heading_rad : array_like, shape (m,)
            Heading, math convention.
        implement_on : array_like of bool, shape (m,)
            The path is a working stretch here.
        s_m : array_like, shape (m,), optional
            Distance along the planned path (coverage control needs it).
        """
        on = np.asarray(implement_on, bool)
        passes = self.passes.step(heading_rad, on)
        sensed = _Sensed.of(x_m, y_m, speed_m_s, heading_rad)
        commanded, actual = self.engine.step(sensed, on, s_m, passes, self.tick)
        self.tick += on.size
        imp = self.implement
        return SectionStates(actual, imp.section_widths, imp.section_offsets_m, passes, commanded)

    def state(self) -> dict:
        """What the switch carries from one `step` to the next, as plain data (JSON-safe): the tick,
        the pass tracker and the switching's own memory (coverage: the coverage map, packed, the last
        commands, the gates, what landed since the last pass ended)."""
        return {"tick": self.tick, "passes": self.passes.state(), "engine": self.engine.state()}

    def set_state(self, state: dict) -> None:
        """Continue from what `state` returned (also after JSON: lists for arrays)."""
        self.tick = int(state["tick"])
        self.passes.set_state(state["passes"])
        self.engine.set_state(state["engine"])


def switch_sections(track: dict, implement: Implement, field_polygon, path: CoveragePath | None = None,
                    map_cell_m: float | None = None, measured=None, period_s: float | None = None
                    ) -> SectionStates:
    """Section states over a whole run: one `SectionSwitch.step` over the track.

    Parameters
    ----------
    track : dict of ndarray, shape (n,)
        ``time_s`` (evenly spaced), ``x_m``, ``y_m`` (field CRS, metres), ``heading_rad`` (math
        convention), ``speed_m_s``, ``implement_on`` (bool: the path is a working stretch) and, for
        coverage control, ``s_m`` (distance along `path`).
    implement, field_polygon, path, map_cell_m
        As for `SectionSwitch`.
    measured : (x_m, y_m, speed_m_s), optional
        What the terminal knows (GNSS position, sensed ground speed), arrays of shape (n,). Default:
        the true ones.
    period_s : float, optional
        Tick length; default: the track's median time step.
    """
    if period_s is None:
        period_s = _period_s(np.asarray(track["time_s"], float))
    if measured is None:
        measured = (track["x_m"], track["y_m"], track["speed_m_s"])
    switch = SectionSwitch(implement, field_polygon, path, period_s, map_cell_m)
    x, y, v = measured
    return switch.step(x, y, track["heading_rad"], v, track["implement_on"], track.get("s_m"))


# --- the three ways of switching ----------------------------------------------------------------
class _Memoryless:
    """A way of switching that carries nothing from one `step` to the next."""

    def state(self) -> None:
        return None

    def set_state(self, state) -> None:
        pass


class _AllOn(_Memoryless):
    """``"off"``: every section applies while the implement is on."""

    def __init__(self, implement, polygon, path, period_s, map_cell_m):
        self.sections = implement.sections

    def step(self, sensed, on, s_m, passes, tick):
        actual = np.repeat(on[:, None], self.sections, axis=1)
        return actual, actual


class _Boundary(_Memoryless):
    """``"boundary"``: a section applies while the implement is on and its centre, at the control
    core's predicted landing point, lies inside the field (no latency)."""

    def __init__(self, implement, polygon, path, period_s, map_cell_m):
        self.implement, self.polygon = implement, polygon

    def step(self, sensed, on, s_m, passes, tick):
        lx, ly = sensed.ahead(self.implement.delivery_delay_s)
        actual = self.implement.sections_on(self.polygon, lx, ly, sensed.heading_rad, on)
        return actual, actual


class _Coverage:
    """Coverage-based switching, stateful across `step` calls (see the module's docstring)."""

    def __init__(self, implement, polygon, path, period_s, map_cell_m):
        if path is None:
            raise ValueError("coverage section control needs the planned path")
        self.implement, self.path, self.period_s = implement, path, period_s
        self.segment_works = np.array([seg.implement_on for seg in path.segments], bool)
        self.lag = _Lags.of(implement, period_s)
        self.raster = CoverageRaster(polygon, coverage_cell_m(implement, map_cell_m),
                                     margin_m=implement.width_m)
        self.strip = _Strip.across(implement, self.raster.cell_m)
        self.limits = (implement.section_overlap_pct, implement.boundary_overlap_pct)
        # The strip a tick's product covers is read at its middle, half a tick's travel further on.
        self.lead_on_s = implement.delivery_delay_s + implement.section_on_delay_s + period_s / 2
        self.lead_off_s = implement.delivery_delay_s + implement.section_off_delay_s + period_s / 2
        sections = implement.sections
        self.last_command = np.zeros(sections, bool)
        self.gates = GateLine(self.lag.on, self.lag.off, sections)
        self.last_pass = -1
        # Since the last pass ended (tick `mark_from`): the sensed poses, and the gates from
        # `mark_from - delivery` (whose product lands at those poses), in chunks.
        self.mark_from, self.gate_from = 0, 0
        self.poses: list[np.ndarray] = []
        self.gate_rows: list[np.ndarray] = [np.zeros((0, sections), bool)]

    def step(self, sensed, on, s_m, passes, tick):
        m, sections = on.size, self.implement.sections
        if s_m is None:
            raise ValueError("coverage section control needs s_m, the distance along the planned path")
        s_m = np.asarray(s_m, float)
        self.poses.append(np.stack([sensed.x_m, sensed.y_m, sensed.cos, sensed.sin]))
        ahead = [(sensed.ahead(lead), self._working(s_m + sensed.speed_m_s * lead))
                 for lead in (self.lead_on_s, self.lead_off_s)]
        before = np.concatenate(([self.last_pass], passes[:-1]))
        ends = np.flatnonzero((before >= 0) & (passes != before))
        commanded, actual = np.zeros((m, sections), bool), np.zeros((m, sections), bool)
        for a, b in zip(np.concatenate(([0], ends)), np.concatenate((ends, [m])), strict=True):
            if a in ends:  # a pass ended here: what landed up to now is treated for what follows
                self._mark(tick + int(a))
            if b <= a:
                continue
            won, woff = (self._wanted(xy, work, sensed, a, b) for xy, work in ahead)
            commanded[a:b] = command(won, woff, self.lag.on_first, self.last_command)
            self.last_command = commanded[b - 1]
            actual[a:b] = self.gates.push(commanded[a:b], tick + int(a))
            self.gate_rows.append(actual[a:b])
        if m:
            self.last_pass = int(passes[-1])
        return commanded, actual

    def state(self) -> dict:
        poses = np.concatenate(self.poses, axis=1)
        gates = np.concatenate(self.gate_rows)
        return {"last_command": self.last_command.tolist(), "gates": self.gates.state(),
                "last_pass": self.last_pass, "mark_from": self.mark_from, "gate_from": self.gate_from,
                "poses": poses.tolist(), "gate_rows": gates.tolist(), "treated": self.raster.treated()}

    def set_state(self, state: dict) -> None:
        sections = self.implement.sections
        self.last_command = np.asarray(state["last_command"], bool).reshape(sections)
        self.gates.set_state(state["gates"])
        self.last_pass = int(state["last_pass"])
        self.mark_from, self.gate_from = int(state["mark_from"]), int(state["gate_from"])
        self.poses = [np.asarray(state["poses"], float).reshape(4, -1)]
        self.gate_rows = [np.asarray(state["gate_rows"], bool).reshape(-1, sections)]
        self.raster.set_treated(state["treated"])

    def _working(self, s_m):
        """Whether the planned path works at distances `s_m` along it (False beyond its end)."""
        return self.segment_works[self.path.segment_at(s_m)] & (s_m < self.path.length_m)

    def _wanted(self, xy, working, sensed, a, b):
        out = np.zeros((b - a, self.implement.sections), bool)
        for lo in range(a, b, MAX_WANTED_TICKS):
            hi = min(b, lo + MAX_WANTED_TICKS)
            out[lo - a:hi - a] = self.raster.wanted(self.strip, xy[0][lo:hi], xy[1][lo:hi], sensed.cos[lo:hi],
                                                    sensed.sin[lo:hi], *self.limits) & working[lo:hi, None]
        return out

    def _mark(self, end: int) -> None:
        """Mark as treated what landed at the poses [mark_from, end), and start again from `end`."""
        poses = np.concatenate(self.poses, axis=1)  # poses from tick mark_from on
        gates = np.concatenate(self.gate_rows)  # gates from tick gate_from on
        # Product landing at pose q left the meter at tick q - delivery; gates before tick 0 were closed.
        metered = np.arange(self.mark_from, end) - self.lag.delivery
        landed = gates[np.maximum(metered - self.gate_from, 0)] & (metered >= 0)[:, None]
        if landed.any():
            self.raster.mark(self.strip, Poses(*poses[:, :end - self.mark_from + 1]), 0, landed)
        keep = max(end - self.lag.delivery, self.gate_from)
        self.poses, self.gate_rows = [poses[:, end - self.mark_from:]], [gates[keep - self.gate_from:]]
        self.mark_from, self.gate_from = end, keep


SWITCHING = {"coverage": _Coverage, "boundary": _Boundary, "off": _AllOn}
assert set(SWITCHING) == set(SECTION_CONTROL_MODES)


# --- passes ----------------------------------------------------------------------------------------
class PassTracker:
    """Pass of each tick, tick by tick: runs of ``implement_on`` numbered in order, a run cut again
    each time its heading has turned by half a circle since the piece began (-1 where the implement
    is off). Carried across `step` calls, so batches give the numbers of one call.

    A piece turning less than half a circle cannot lay its strip on its own earlier strip (except
    where the inner end of the implement pivots in a tight turn); the cut is greedy, so heading
    noise around a multiple of 180 degrees does not cut a straight stretch into many. The heading
    is unwrapped by whole turns counted in integers, so the turned angle is the same however the
    ticks come in batches.
    """

    def __init__(self):
        self.next_id = 0
        self.current = -1  # the open pass, -1 if none
        self.reference = 0.0  # unwrapped heading where the open piece began
        self.turns = 0  # whole turns unwrapped so far
        self.last_heading = None

    def step(self, heading_rad, implement_on) -> np.ndarray:
        on = np.asarray(implement_on, bool)
        h = np.asarray(heading_rad, float)
        out = np.full(on.size, -1, np.int64)
        if not on.size:
            return out
        prev = h[0] if self.last_heading is None else self.last_heading
        jumps = np.rint(np.diff(h, prepend=prev) / (2 * math.pi)).astype(np.int64)
        turns = self.turns - np.cumsum(jumps)
        unwrapped = h + 2 * math.pi * turns
        self.turns, self.last_heading = int(turns[-1]), float(h[-1])
        for a, b in runs_of(on):
            if a > 0 or self.current < 0:  # a new run of work: a new pass
                self._begin(unwrapped[a])
            pos = a
            while pos < b:
                turned = np.abs(unwrapped[pos:b] - self.reference) >= math.pi
                cut = pos + int(np.argmax(turned)) if turned.any() else b
                out[pos:cut] = self.current
                if cut < b:
                    self._begin(unwrapped[cut])
                pos = cut
        if not on[-1]:
            self.current = -1
        return out

    def state(self) -> dict:
        return {"next_id": self.next_id, "current": self.current, "reference": self.reference,
                "turns": self.turns, "last_heading": self.last_heading}

    def set_state(self, state: dict) -> None:
        self.next_id, self.current = int(state["next_id"]), int(state["current"])
        self.reference, self.turns = float(state["reference"]), int(state["turns"])
        last = state["last_heading"]
        self.last_heading = None if last is None else float(last)

    def _begin(self, heading: float) -> None:
        self.current, self.next_id = self.next_id, self.next_id + 1
        self.reference = float(heading)


def pass_index(heading_rad, implement_on) -> np.ndarray:
    """Pass of each tick of a whole track (see `PassTracker`): -1 where the implement is off."""
    return PassTracker().step(heading_rad, implement_on)


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


def command(wanted_on, wanted_off, on_first: bool, before) -> np.ndarray:
    """The terminal's command per tick from the two look-aheads; shape (m, sections).

    ``wanted_on[t]``: product is wanted where it would start landing if the section were commanded
    on at t; ``wanted_off[t]``: ... where it would stop landing if commanded off at t. When both
    agree the command follows them. When only the longer look-ahead wants product, the section
    switches (or stays) on; when only the shorter one does, it keeps its state (on: product still
    lands on wanted ground until it could stop; off: starting now would land on unwanted ground).
    The result: product starts and stops landing where wanted starts and stops (as far as the
    look-aheads predicted it), except that a gap shorter than the two delays' difference is
    bridged (overlap) and an island that short is skipped: the section cannot stop and restart, or
    start and stop, in time.

    ``before`` (sections,) is the command before the first tick (causal: a tick's command depends
    on that and the ticks up to it only).
    """
    decided = wanted_on | ~wanted_off
    value = wanted_on if on_first else wanted_off
    last = np.where(decided, np.arange(decided.shape[0], dtype=np.int32)[:, None], np.int32(-1))
    np.maximum.accumulate(last, axis=0, out=last)
    held = np.take_along_axis(value, np.maximum(last, 0), axis=0)
    return np.where(last >= 0, held, np.asarray(before, bool)[None, :])


class GateLine:
    """Gates following commands after their latencies, tick by tick across `push` calls.

    Each command takes effect `on_ticks` (switching on) or `off_ticks` (switching off) after it is
    given, and a gate follows the most recent command that has taken effect, so an on command
    cancelled before it took effect never opens the gate. All gates are closed before tick 0.
    """

    def __init__(self, on_ticks: int, off_ticks: int, sections: int):
        self.on, self.off = on_ticks, off_ticks
        self.span = max(on_ticks, off_ticks)
        self.history = np.zeros((self.span, sections), bool)  # the last `span` commands
        self.arrived = np.full(sections, -1, np.int64)  # tick of the command each gate follows
        self.value = np.zeros(sections, bool)  # each gate's state

    def push(self, commanded, tick: int) -> np.ndarray:
        """Gate states of the ticks `tick`, `tick` + 1, ... whose commands are `commanded` (m, sections)."""
        m = commanded.shape[0]
        if m == 0:
            return np.zeros(commanded.shape, bool)
        ext = np.concatenate((self.history, commanded))  # from tick - span
        t = tick + np.arange(m, dtype=np.int64)[:, None]
        rows = np.arange(m)
        src_on, src_off = ext[self.span - self.on + rows], ext[self.span - self.off + rows]
        events = np.maximum(np.where(src_on & (t - self.on >= 0), t - self.on, -1),
                            np.where(~src_off & (t - self.off >= 0), t - self.off, -1))
        arrived = np.maximum.accumulate(np.maximum(events, self.arrived[None, :]), axis=0)
        fresh = arrived > self.arrived[None, :]
        index = np.clip(arrived - (tick - self.span), 0, ext.shape[0] - 1)
        gates = np.where(fresh, np.take_along_axis(ext, index, axis=0), self.value[None, :])
        self.arrived, self.value = arrived[-1], gates[-1]
        self.history = ext[ext.shape[0] - self.span:]
        return gates


    def state(self) -> dict:
        return {"history": self.history.tolist(), "arrived": self.arrived.tolist(),
                "value": self.value.tolist()}

    def set_state(self, state: dict) -> None:
        sections = self.value.size
        self.history = np.asarray(state["history"], bool).reshape(self.span, sections)
        self.arrived = np.asarray(state["arrived"], np.int64).reshape(sections)
        self.value = np.asarray(state["value"], bool).reshape(sections)


def gate(commanded, on_ticks: int, off_ticks: int) -> np.ndarray:
    """Gate state per tick of a whole run (see `GateLine`); shape as `commanded`."""
    return GateLine(on_ticks, off_ticks, commanded.shape[1]).push(commanded, 0)


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
    heading_rad: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    @classmethod
    def of(cls, x_m, y_m, speed_m_s, heading_rad) -> _Sensed:
        x, y, v, h = (np.asarray(a, float) for a in (x_m, y_m, speed_m_s, heading_rad))
        return cls(x, y, v, h, np.cos(h), np.sin(h))

    def ahead(self, delay_s: float):
        """Where the implement will be `delay_s` later, straight ahead at the sensed speed: (x, y).
        The same arithmetic as the control core's landing point, so boundary mode matches it."""
        lead_m = self.speed_m_s * delay_s
        return self.x_m + lead_m * self.cos, self.y_m + lead_m * self.sin


def _period_s(time_s: np.ndarray) -> float:
    return float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0


@dataclass(frozen=True)
class Poses:
    """Poses along which strips are outlined: the true ones (the worked area), the sensed ones (the
    terminal's coverage map)."""

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
        if (self.counts == self.counts[0]).all():  # equal sections: one reshaped sum, 5x faster
            return flags.reshape(self.counts.size, self.counts[0], -1).sum(axis=1, dtype=np.int32).T
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
        cell = row.astype(np.int32)  # at most MAX_COVERAGE_CELLS: int32 indices (half the work of int64)
        cell *= self.cols
        cell += col.astype(np.int32)
        code = self.state.reshape(-1)[cell]
        treated, outside = strip.count(code & TREATED), strip.count(code >> 1)
        counts = strip.counts
        return (treated * 100.0 <= treated_pct * counts) & (outside * 100.0 <= outside_pct * counts)

    def treated(self) -> str:
        """The treated cells as plain data: the `TREATED` bits packed, zlib-compressed, base64 (a
        coverage map of millions of cells stays a few kilobytes; `OUTSIDE` follows from the field)."""
        bits = np.packbits((self.state & TREATED).astype(bool).reshape(-1))
        return base64.b64encode(zlib.compress(bits.tobytes(), 6)).decode("ascii")

    def set_treated(self, packed: str) -> None:
        """Restore the treated cells from what `treated` returned."""
        bits = np.frombuffer(zlib.decompress(base64.b64decode(packed)), np.uint8)
        treated = np.unpackbits(bits, count=self.state.size).reshape(self.state.shape).astype(bool)
        self.state = (self.state & OUTSIDE) | np.where(treated, TREATED, np.uint8(0))

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


# --- a run's section states ----------------------------------------------------------------------
def run_section_states(track: dict, control: dict, implement) -> SectionStates:
    """The gates of a run's control-core arrays (``sections_on``, and ``sections_commanded`` when
    given) with the implement's section widths and offsets and the passes of its true track."""
    return SectionStates(np.asarray(control["sections_on"], bool), implement.section_widths,
                         implement.section_offsets_m, pass_index(track["heading_rad"], track["implement_on"]),
                         control.get("sections_commanded"))
