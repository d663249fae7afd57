"""Switching: which sections' gates are open, tick by tick, by ``[implement] section_control``.

Three modes (`SWITCHING`): ``"coverage"`` as terminals do it (a section switches off ahead of ground
already treated, outside the field or off the planned path's working stretches), ``"boundary"`` (a
section applies while its centre's predicted landing point lies in the field) and ``"off"`` (every
section applies while the implement is on).

With ``side_steps`` (a spinner's sides shortened in steps, `SectionSwitch`) coverage control decides
on each side's steps as on sections of their own and counts the steps on (`SectionStates.steps_on`).

`SectionSwitch.step` is causal and carries everything over, so a track stepped in batches of any size
gives the states of one step over the whole track: `vrsim run` steps once, the Zenoh controller
service once per lockstep batch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from vrsim.services.sim.sections.coverage import CoverageRaster, coverage_cell_m
from vrsim.services.sim.sections.gates import GateLine, command
from vrsim.services.sim.sections.motion import Motion, MotionTrend
from vrsim.services.sim.sections.passes import PassTracker, pass_index
from vrsim.services.sim.sections.strips import Poses, Strip
from vrsim.vehicle import CoveragePath, Implement
from vrsim.vehicle.implement import SECTION_CONTROL_MODES
from vrsim.vehicle.machines import DEFAULT_KIND

# The run's control array of `SectionStates.steps_on` (`services.sim.core.ControlCore`), (n, 2) per tick.
STEPS_KEY = "side_steps_on"
_MAX_WANTED_TICKS = 20_000  # decisions read off the raster in chunks of this many ticks (memory)


@dataclass(frozen=True)
class SectionStates:
    """Per-tick section states of a run (or of one batch of ticks): gates, commands, passes; widths in m.

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
    motion : Motion, optional
        What the terminal knew of the motion at each tick (pose, speed, acceleration, yaw rate), from
        which it looked ahead; None where only the gates are known.
    steps_on : ndarray of int, shape (n, 2), optional
        A spinner's sides shortened in steps over treated ground (`SectionSwitch`'s ``side_steps``):
        how many of each side's steps (left, right) are on, from the centre line out (0: the side
        off); None: every open side's whole width.
    """

    actual: np.ndarray
    widths_m: np.ndarray
    offsets_m: np.ndarray
    pass_index: np.ndarray
    commanded: np.ndarray | None = None
    motion: Motion | None = None
    steps_on: np.ndarray | None = None

    @property
    def width_on_m(self) -> np.ndarray:
        """Working width whose gates are open at each tick, m, shape (n,): the width the meter's
        target is computed for."""
        return self.actual @ self.widths_m

    @property
    def count_on(self) -> np.ndarray:
        """Number of sections whose gates are open at each tick, int, shape (n,)."""
        return self.actual.sum(axis=1)


class SectionSwitch:
    """Section states tick by tick (ticks of `period_s` s), by the implement's ``section_control``.

    Carried across `step` calls: batches of any size give the states of one call.

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
    side_steps : int
        A spinner's sides (its sections: the left and the right half of the working width) shortened
        in this many steps over treated ground (`_SteppedCoverage`, coverage control only); 1: each
        section only on or off.
    """

    def __init__(self, implement: Implement, field_polygon, path: CoveragePath | None = None,
                 period_s: float = 0.05, map_cell_m: float | None = None, side_steps: int = 1):
        self.implement = implement
        self.passes = PassTracker()
        self.trend = MotionTrend(period_s)
        if side_steps > 1 and implement.section_control == "coverage":
            self.engine = _SteppedCoverage(implement, field_polygon, path, period_s, map_cell_m, side_steps)
        else:
            self.engine = SWITCHING[implement.section_control](implement, field_polygon, path, period_s,
                                                               map_cell_m)
        self.tick = 0

    def step(self, x_m, y_m, heading_rad, speed_m_s, implement_on, s_m=None) -> SectionStates:
        """The states of the next m ticks, from positions in m, heading in rad, speed in m/s.

        Parameters
        ----------
        x_m, y_m, speed_m_s : array_like, shape (m,)
            What the terminal knows: the GNSS position (field CRS, m), the sensed ground speed (m/s).
        heading_rad : array_like, shape (m,)
            Heading, math convention.
        implement_on : array_like of bool, shape (m,)
            The path is a working stretch here.
        s_m : array_like, shape (m,), optional
            Distance along the planned path (coverage control needs it).
        """
        on = np.asarray(implement_on, bool)
        passes = self.passes.step(heading_rad, on)
        motion = self.trend.step(x_m, y_m, heading_rad, speed_m_s)
        commanded, actual, steps_on = self.engine.step(motion, on, s_m, passes, self.tick)
        self.tick += on.size
        imp = self.implement
        return SectionStates(actual, imp.section_widths, imp.section_offsets_m, passes, commanded, motion,
                             steps_on)

    def state(self) -> dict:
        """What the switch carries from one `step` to the next, as plain data (JSON-safe): the tick,
        the pass tracker, the motion trend and the switching's own memory (coverage: the coverage map,
        packed, the last commands, the gates, what landed since the last pass ended)."""
        return {"tick": self.tick, "passes": self.passes.state(), "trend": self.trend.state(),
                "engine": self.engine.state()}

    def set_state(self, state: dict) -> None:
        """Continue from what `state` returned (also after JSON: lists for arrays)."""
        self.tick = int(state["tick"])
        self.passes.set_state(state["passes"])
        self.trend.set_state(state["trend"])
        self.engine.set_state(state["engine"])


def switch_sections(track: dict, implement: Implement, field_polygon, path: CoveragePath | None = None,
                    map_cell_m: float | None = None, measured=None, period_s: float | None = None
                    ) -> SectionStates:
    """Section states over a whole run (positions m, speed m/s): one `SectionSwitch.step` over the track.

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
        Tick length, s; default: the track's median time step.
    """
    if period_s is None:
        period_s = _period_s(np.asarray(track["time_s"], float))
    if measured is None:
        measured = (track["x_m"], track["y_m"], track["speed_m_s"])
    switch = SectionSwitch(implement, field_polygon, path, period_s, map_cell_m)
    x, y, v = measured
    return switch.step(x, y, track["heading_rad"], v, track["implement_on"], track.get("s_m"))


def run_section_states(track: dict, control: dict, implement) -> SectionStates:
    """The `SectionStates` of a run's control-core arrays: bool (n, sections) per tick and section.

    The gates are ``control["sections_on"]`` (the commands ``sections_commanded`` when given), with
    the implement's section widths and offsets (m), the passes of the true track and a spinner's
    steps on (``side_steps_on``, `STEPS_KEY`, when given).
    """
    return SectionStates(np.asarray(control["sections_on"], bool), implement.section_widths,
                         implement.section_offsets_m, pass_index(track["heading_rad"], track["implement_on"]),
                         control.get("sections_commanded"), steps_on=control.get(STEPS_KEY))


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

    def step(self, motion, on, s_m, passes, tick):
        actual = np.repeat(on[:, None], self.sections, axis=1)
        return actual, actual, None


class _Boundary(_Memoryless):
    """``"boundary"``: a section applies while the implement is on and its centre, where the
    implement will be when product metered now lands (`Motion.ahead`), lies inside the field (no
    latency)."""

    def __init__(self, implement, polygon, path, period_s, map_cell_m):
        self.implement, self.polygon = implement, polygon

    def step(self, motion, on, s_m, passes, tick):
        lx, ly, cos, sin = motion.ahead(self.implement.delivery_delay_s)
        actual = self.implement.sections_on(self.polygon, lx, ly, np.arctan2(sin, cos), on)
        return actual, actual, None


class _Coverage:
    """``"coverage"``, as terminals do it; stateful across `step` calls.

    A section switches off when more than ``section_overlap_pct`` of its strip would land on treated
    ground, more than ``boundary_overlap_pct`` outside the field, or beyond the planned path's
    working stretch (in a turn), and on again over untreated ground in the field. It decides ahead
    by its own latency plus the delivery delay: where its strip will be is predicted from the
    sensed pose, speed, acceleration and yaw rate (`Motion.ahead`: each section by its own ground
    speed), whether the path works there is read off the plan at the distance travelled by then.
    A section whose own ground speed is at most ``section_min_speed_m_s`` is off, as a terminal's slow
    speed cutoff (AgOpenGPS compares each section's speed with it): the inner end of a turn tighter
    than its offset pivots or moves backwards, and a gated meter's share of product for its width
    would pile up where it stands.
    The gates follow the commands after ``section_on_delay_s`` / ``section_off_delay_s``
    (`GateLine`). Exact at constant acceleration and yaw rate; where they change within the
    look-ahead, longer latencies leave more skips and overlap, as the terminals' manuals warn.

    Vectorized: the coverage raster changes only where a pass ends (`PassTracker`), when all that
    landed since the previous end is marked, so the decisions of all ticks between two ends are read
    off it at once. The price: ground a pass treated itself counts only once the pass ends (inner
    sections of a turn tighter than half the working width keep applying where they pivot), and a
    decision looking across a pass's end does not see that pass's own strips yet.
    """

    def __init__(self, implement, polygon, path, period_s, map_cell_m):
        if path is None:
            raise ValueError("coverage section control needs the planned path")
        self.implement, self.path, self.period_s = implement, path, period_s
        self.segment_works = np.array([seg.implement_on for seg in path.segments], bool)
        self.lag = _Lags.of(implement, period_s)
        self.raster = CoverageRaster(polygon, self._cell_m(implement, map_cell_m), margin_m=implement.width_m)
        self.strip = Strip.across(implement, self.raster.cell_m)
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

    def step(self, motion, on, s_m, passes, tick):
        m, sections = on.size, self.implement.sections
        if s_m is None:
            raise ValueError("coverage section control needs s_m, the distance along the planned path")
        s_m = np.asarray(s_m, float)
        heading = motion.heading_rad
        self.poses.append(np.stack([motion.x_m, motion.y_m, np.cos(heading), np.sin(heading)]))
        imp = self.implement
        moving = motion.ground_speed_m_s(imp.section_offsets_m) > imp.section_min_speed_m_s
        before = np.concatenate(([self.last_pass], passes[:-1]))
        ends = np.flatnonzero((before >= 0) & (passes != before))
        commanded, actual = np.zeros((m, sections), bool), np.zeros((m, sections), bool)
        for a, b in zip(np.concatenate(([0], ends)), np.concatenate((ends, [m])), strict=True):
            if a in ends:  # a pass ended here: what landed up to now is treated for what follows
                self._mark(tick + int(a))
            if b <= a:
                continue
            commanded[a:b] = command(*self._both_wanted(motion, s_m, moving, a, b), self.lag.on_first,
                                     self.last_command)
            self.last_command = commanded[b - 1]
            actual[a:b] = self.gates.push(commanded[a:b], tick + int(a))
            self.gate_rows.append(actual[a:b])
        if m:
            self.last_pass = int(passes[-1])
        return commanded, actual, None

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

    def _cell_m(self, implement, map_cell_m) -> float:
        """The coverage map's cell, m (`coverage_cell_m`)."""
        return coverage_cell_m(implement, map_cell_m)

    def _working(self, s_m):
        """Whether the planned path works at distances `s_m` along it (False beyond its end)."""
        return self.segment_works[self.path.segment_at(s_m)] & (s_m < self.path.length_m)

    def _both_wanted(self, motion, s_m, moving, a: int, b: int):
        """`gates.command`'s two look-aheads (on, off) of ticks [a, b): bool (b - a, sections) each.

        The command follows one of them (the longer lead's) and the other only decides a section
        where that one does not: on first, where product is not wanted on; off first, where it is
        wanted off. So the other is predicted and read off the raster only at the ticks where it decides
        a section (a few per cent of them); elsewhere it is False, which is never read.
        """
        on_first = self.lag.on_first
        lead_s, other_s = (self.lead_on_s, self.lead_off_s) if on_first else (self.lead_off_s, self.lead_on_s)
        value = self._wanted(*self._ahead(motion, s_m, lead_s, slice(a, b)), 0, b - a) & moving[a:b]
        rows = a + np.flatnonzero(~value.all(axis=1) if on_first else value.any(axis=1))
        other = np.zeros_like(value)
        if rows.size:
            wanted = self._wanted(*self._ahead(motion, s_m, other_s, rows), 0, rows.size)
            other[rows - a] = wanted & moving[rows]
        return (value, other) if on_first else (other, value)

    def _ahead(self, motion, s_m, lead_s: float, ticks):
        """The pose (x, y, cos, sin) predicted `lead_s` ahead of `ticks` (a slice or indices) and whether
        the planned path works there."""
        part = motion.part(ticks)
        distance_m, moving_s = part.travel(lead_s)
        return part.pose_after(distance_m, moving_s), self._working(s_m[ticks] + distance_m)

    def _wanted(self, pose, working, a, b):
        """Whether each section's product is wanted across the predicted `pose` (x, y, cos, sin) of
        ticks [a, b): bool (b - a, sections)."""
        out = np.zeros((b - a, self.implement.sections), bool)
        for lo in range(a, b, _MAX_WANTED_TICKS):
            hi = min(b, lo + _MAX_WANTED_TICKS)
            out[lo - a:hi - a] = self._decide(*(p[lo:hi] for p in pose)) & working[lo:hi, None]
        return out

    def _decide(self, x_m, y_m, cos, sin):
        """Whether each section's product is wanted on its strip across the poses: bool (m, sections)."""
        return self.raster.wanted(self.strip, x_m, y_m, cos, sin, *self.limits)

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


class _SteppedCoverage(_Coverage):
    """``"coverage"`` for a spinner whose sides shorten in `steps` steps over treated ground.

    Each side (the left and the right half of the working width) is cut into `steps` equal bands
    from the centre line out. A side's reach is the largest number of steps k whose strip, its
    innermost k bands, lies no more than ``section_overlap_pct`` on treated ground and no more than
    ``boundary_overlap_pct`` outside the field (k = steps: the side's whole half, as a section is
    decided; 0: the side off); its bands up to k are wanted, the others not (a spinner's spread
    shortens from the outside in). Each band is then switched as a section of its own (its
    latencies, its strip marked treated where it landed). A side's steps on are its bands on from
    the centre line out; a section is on where its side's innermost band is (one section: either
    side's).
    """

    def __init__(self, implement, polygon, path, period_s, map_cell_m, steps: int):
        self.steps, self.sides = steps, implement
        width = implement.width_m / (2 * steps)
        bands = dataclasses.replace(implement, kind=DEFAULT_KIND, machine=None, sections=2 * steps,
                                    section_widths_m=(width,) * (2 * steps))
        super().__init__(bands, polygon, path, period_s, map_cell_m)
        self._reach = _BandReach(steps, self.strip.counts, *self.limits)

    def step(self, motion, on, s_m, passes, tick):
        commanded, actual, _ = super().step(motion, on, s_m, passes, tick)
        # A side is on where its innermost band is (its steps on from the centre line out: at least 1).
        inner = [self.steps - 1, self.steps]
        return self._sides(commanded[:, inner]), self._sides(actual[:, inner]), self._reach.steps_on(actual)

    def _cell_m(self, implement, map_cell_m) -> float:
        """The sides' coverage cell (`coverage_cell_m`): as fine as a whole side's, not a band's (the
        coverage map's work grows with the square of its cells)."""
        return coverage_cell_m(self.sides, map_cell_m)

    def _decide(self, x_m, y_m, cos, sin):
        return self._reach.wanted(*self.raster.flagged(self.strip, x_m, y_m, cos, sin))

    def _sides(self, on: np.ndarray) -> np.ndarray:
        """The sections' gates (m, sections) from whether each side is on (m, 2)."""
        return on if self.sides.sections == 2 else on.any(axis=1, keepdims=True)


class _BandReach:
    """A spinner's sides cut into `steps` bands each, the bands left to right (``2 * steps``, the left
    side's outermost first): the bands wanted from their points on treated ground and outside the field,
    and each side's steps on from the bands' gates, as sums over a side's bands from the centre line out.

    The sums over bands are products with 0/1 matrices in float32: the counts are small integers (a
    strip's points times 100 stay far below 2**24), so every sum is exact in any order, and the limits'
    comparisons are those of the counts as integers.
    """

    def __init__(self, steps: int, counts: np.ndarray, treated_pct: float, outside_pct: float):
        bands = np.arange(2 * steps)
        right = bands >= steps
        out = np.where(right, bands - steps, steps - 1 - bands)   # a band's place out from the centre line
        same = right[:, None] == right[None, :]
        # within[i, j]: band i lies in band j's strip (its side's bands from the centre line out to j);
        # beyond[i, j]: band i is band j or lies further out on its side.
        within = same & (out[:, None] <= out[None, :])
        self._within_pct = (within * 100.0).astype(np.float32)
        self._beyond = (same & (out[:, None] >= out[None, :])).astype(np.float32)
        total = np.asarray(counts, np.int64) @ within.astype(np.int64)   # each band's strip's points
        self._limits = (treated_pct * total, outside_pct * total)
        # A side's bands on (bits from the centre line out) -> its steps on: the bits on before the first off.
        self._code = np.zeros((2 * steps, 2), np.int64)
        self._code[:steps, 0] = 1 << out[:steps]
        self._code[steps:, 1] = 1 << out[steps:]
        codes = np.arange(1 << steps)
        self._leading = np.array([(c ^ (c + 1)).bit_length() - 1 for c in codes.tolist()], np.int64)

    def wanted(self, treated: np.ndarray, outside: np.ndarray) -> np.ndarray:
        """Whether each band's product is wanted, bool (m, bands), from each band's points on treated
        ground and outside the field (int, (m, bands)): a side's reach is the largest number of bands
        from the centre line whose strip lies no more than the limits' percentages on treated ground and
        outside (0: none), its bands within it wanted."""
        treated_limit, outside_limit = self._limits
        fits = ((treated.astype(np.float32) @ self._within_pct <= treated_limit)
                & (outside.astype(np.float32) @ self._within_pct <= outside_limit))
        return fits.astype(np.float32) @ self._beyond > 0   # a strip at or beyond the band fits

    def steps_on(self, gates: np.ndarray) -> np.ndarray:
        """Each side's steps on (m, 2; int): its bands' gates (bool (m, bands)) on from the centre line
        out, up to the first off."""
        return self._leading[gates @ self._code]


# The ways of switching by ``[implement] section_control``: name -> class.
SWITCHING = {"coverage": _Coverage, "boundary": _Boundary, "off": _AllOn}
assert set(SWITCHING) == set(SECTION_CONTROL_MODES)


def _period_s(time_s: np.ndarray) -> float:
    return float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0


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

