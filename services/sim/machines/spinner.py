"""``spinner``: a twin-disc spinner spreader (`vehicle.spinner.SpinnerSpec`).

Two metering drives, the left and the right disc, each metering half of ``kg_per_rev`` per
revolution with its own control loop (per-side rate). Each side's rate is looked up at its own
landing point: the centre of the product that side throws (its half of the transverse pattern,
`TransversePattern.side_centre_m`, across the pose predicted along the arc), ``throw_distance_m``
behind the discs; its target is for its own ground speed in a turn (``v - yaw_rate * offset``, at
least 0, as `section_drives`' turn compensation) over the driving width ``width_m``: with equal
rates the two discs together meter what one shaft would over the driving width.

Section control: the implement's sections are the sides (one section: both sides together; two:
each side its own, the left first); the switch (``section_control``) turns a side off on its half of
the driving width. Over treated ground coverage control shortens each side's reach in ``side_steps``
steps (`side_steps`: the switch decides each side's steps in stage 1, `SectionStates.steps_on`, the
run's ``side_steps_on``). At the field boundary each side's reach is cut (`SpinnerSpec.side_reach_m`:
exactly at the boundary with ``border_spreading``, else in ``side_steps`` steps), measured from
where its product lands, across; a side's reach is the shorter of the two. A cut side meters the
share of its half that lies within its reach (`TransversePattern.side_share`), so a cut pattern is
the uncut one with what would have landed beyond the reach left in the hopper. A side whose reach is
0 is off.

Deposition: each side's product lands through `maps.SpinnerThrow` (the disc centre's travel on the
true path ``delivery_delay_s`` later, thrown ``throw_distance_m`` behind, across the side to its
reach), one item per side and joined span of ticks (`StripPlan` of the two sides along the centre
line; a span ends where its reach over treated ground changes), so it goes through both modes of the
deposition engine and sweeps' batched variants.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from vrsim.maps import SpinnerThrow
from vrsim.services.sim.machines.base import Machine
from vrsim.services.sim.machines.registry import register_machine
from vrsim.services.sim.section_landing import StripPlan
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle.spinner import SpinnerSpec

__all__ = ["Spinner", "ThrowPlan"]

SIDES = np.array([1.0, -1.0])   # drive 0: the left disc (+1, left of travel), drive 1: the right disc
MIN_REACH_M = 0.1  # a side whose product the terminal let through where the true pose leaves no room
ROOM_CHUNK = 2_000_000   # points x boundary segments at a time in the ray casting (memory)
# A point farther than a side's full reach from the boundary has room for it across either side: only
# the points outside the field eroded by the full reach and this margin are ray cast (`reach_m`). The
# erosion's round corners are chords of their arcs, inside by under 0.5 % of the radius: within the margin.
FAR_MARGIN_M, FAR_MARGIN_SHARE = 1.0, 0.01


@register_machine
class Spinner(Machine):
    """Two discs, a drive and a loop each (see the module's docstring)."""

    kind = "spinner"
    keys = SpinnerSpec
    footprint = SpinnerThrow

    def __init__(self, implement, field_polygon=None):
        super().__init__(implement, field_polygon)
        self.spec = implement.machine
        self.pattern = self.spec.transverse_pattern()
        self.centre_m = np.array([self.pattern.side_centre_m(int(s)) for s in SIDES])
        self._reach_of, self._reach = None, None
        self._far = None   # the field eroded by a side's full reach (`_far_inside`), made when first used

    @property
    def drives(self) -> int:
        return 2

    @property
    def drive_share(self) -> np.ndarray:
        return np.full(2, 0.5)

    @property
    def side_steps(self) -> int:
        return self.spec.side_steps

    def transverse_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        return self.pattern.offset_m, self.pattern.mass_per_m

    def landing(self, motion: Motion, lead_s: float) -> tuple[np.ndarray, ...]:
        x, y, cos, sin = motion.ahead(lead_s)
        x, y = x - self.spec.throw_distance_m * cos, y - self.spec.throw_distance_m * sin
        # Left of the predicted heading (cos, sin) is (-sin, cos).
        return x, y, x[:, None] - sin[:, None] * self.centre_m, y[:, None] + cos[:, None] * self.centre_m

    def sides_on(self, actual: np.ndarray) -> np.ndarray:
        """Whether each side's gate is open, bool (n, 2), from the sections' (n, 1 or 2)."""
        return np.repeat(actual, 2, axis=1) if actual.shape[1] == 1 else actual

    def reach_m(self, x_m, y_m, cos, sin) -> np.ndarray:
        """Each side's reach, m (n, 2), for product landing on the line through (x_m, y_m) along the
        heading (cos, sin): the room to the field boundary across each side, cut by
        `SpinnerSpec.side_reach_m` (half the spread width with no boundary known)."""
        x_m, y_m, cos, sin = (np.asarray(v, float) for v in (x_m, y_m, cos, sin))
        room = np.full((x_m.size, 2), np.inf)   # inf: no boundary within reach
        if self.field_polygon is not None:   # the points far inside have room for the full reach
            near = ~self._far_inside(x_m, y_m)
            room[near] = _room_m(self.field_polygon, x_m[near], y_m[near], -sin[near], cos[near])
        return self.spec.side_reach_m(room)

    def _far_inside(self, x_m, y_m) -> np.ndarray:
        """Whether each point (m) lies inside the field farther than a side's full reach from its
        boundary (bool, shape of `x_m`): the room to the boundary it would be ray cast for is more
        than the full reach in any direction, so `SpinnerSpec.side_reach_m` makes it the full reach."""
        import shapely

        if self._far is None:
            h = self.spec.half_width_m
            self._far = self.field_polygon.buffer(-(h * (1.0 + FAR_MARGIN_SHARE) + FAR_MARGIN_M))
            shapely.prepare(self._far)
        return shapely.contains_xy(self._far, x_m, y_m)

    def steps_reach_m(self, states: SectionStates) -> np.ndarray:
        """Each side's reach over treated ground, m (n, 2): its steps on (`SectionStates.steps_on`,
        from the centre line out) times a step, ``half_width_m / side_steps``; the whole half where
        the switch decides on whole sides."""
        if states.steps_on is None:
            return np.full((len(states.actual), 2), self.spec.half_width_m)
        return np.asarray(states.steps_on) * (self.spec.half_width_m / self.spec.side_steps)

    def _terminal_reach(self, states: SectionStates) -> np.ndarray:
        """Each side's reach as the terminal sets it (n, 2): where product metered now lands, from
        the sensed motion predicted by the delivery delay, cut at the boundary and over treated ground
        (kept for the states it was asked for last: `drive_open` and `drive_targets` ask for the same
        ticks)."""
        if self._reach_of is not states:
            x, y, cos, sin = states.motion.ahead(self.implement.delivery_delay_s)
            throw = self.spec.throw_distance_m
            room = self.reach_m(x - throw * cos, y - throw * sin, cos, sin)
            self._reach_of, self._reach = states, np.minimum(room, self.steps_reach_m(states))
        return self._reach

    def drive_open(self, states: SectionStates) -> np.ndarray:
        return self.sides_on(states.actual) & (self._terminal_reach(states) > 0)

    def drive_speed_m_s(self, motion: Motion) -> np.ndarray:
        """Each side's ground speed where its product lands, m/s (n, 2): ``v - yaw_rate * offset``
        at its centre's offset, at least 0."""
        return np.maximum(motion.ground_speed_m_s(self.centre_m), 0.0)

    def drive_targets(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        imp, reach = self.implement, self._terminal_reach(states)
        # A disc meters half the product per revolution: at full reach it turns at the speed of the one
        # shaft for the driving width; a cut side meters only its pattern's share within the reach.
        share = self.pattern.side_share(SIDES[None, :], reach)
        full_rpm = imp.target_shaft_rpm(rate_kg_ha, self.drive_speed_m_s(states.motion))
        wanted = imp.clip_shaft_rpm(full_rpm * share)
        return np.where(self.sides_on(states.actual) & (reach > 0), wanted, 0.0)

    def combined(self, per_drive: np.ndarray) -> np.ndarray:
        return per_drive @ self.drive_share

    def prescribed(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        """The open sides' rates, averaged (both sides' where neither is open)."""
        on = self.sides_on(states.actual)
        weight = np.where(on.any(axis=1, keepdims=True), on, True).astype(float)
        return (rate_kg_ha * weight).sum(axis=1) / weight.sum(axis=1)

    def deposit_kg(self, control: dict) -> np.ndarray:
        """Each disc's product (n, 2); records without it (the monitor's, rebuilt from the
        machine-level keys) share ``metered_kg`` between the open sides."""
        if "drive_kg" in control:
            return np.asarray(control["drive_kg"])
        on = self.sides_on(np.asarray(control["sections_on"], bool)).astype(float)
        count = on.sum(axis=1, keepdims=True)
        return np.asarray(control["metered_kg"])[:, None] * np.divide(on, count, out=np.zeros(on.shape),
                                                                      where=count > 0)

    def deposition(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                   cell_m: float, ticks=None, tick_m: float | None = None,
                   first_tick: int = 0) -> ThrowPlan:
        # The two sides' spans along the centre line (offsets 0): the discs' travel, joined as strips are,
        # a span ending where the side's reach over treated ground changes (a level: one of its reaches).
        levels, reach_m = self._levels(states)
        count = reach_m.size
        level = (levels[:, None, :] == np.arange(count)[None, :, None]) & (reach_m > 0)[None, :, None]
        on = np.tile(self.sides_on(states.actual), (1, count)) & level.reshape(len(levels), 2 * count)
        width = np.full(2 * count, self.implement.width_m / 2)
        spans = StripPlan.of(track, SectionStates(on, width, np.zeros(2 * count), states.pass_index), delay_s,
                             period_s, cell_m, ticks, tick_m, first_tick, own_drives=True)
        plan = _by_side(spans, count)
        s = plan.strips
        dx, dy = s.x1_m - s.x0_m, s.y1_m - s.y0_m
        length = np.hypot(dx, dy)
        cos = np.divide(dx, length, out=np.zeros(length.shape), where=length > 0)
        sin = np.divide(dy, length, out=np.zeros(length.shape), where=length > 0)
        side_index, steps_reach = s.section % 2, reach_m[s.section // 2]
        throw = self.spec.throw_distance_m
        mid_x, mid_y = (s.x0_m + s.x1_m) / 2 - throw * cos, (s.y0_m + s.y1_m) / 2 - throw * sin
        reach = np.minimum(self.reach_m(mid_x, mid_y, cos, sin)[np.arange(side_index.size), side_index],
                           steps_reach)
        reach = np.where(length > 0, np.maximum(reach, MIN_REACH_M), steps_reach)
        pattern = self.pattern
        return ThrowPlan(plan, SIDES[side_index], reach, pattern.offset_m, pattern.mass_per_m, throw)

    def ownership(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                  cell_m: float, ticks=None, tick_m: float | None = None, first_tick: int = 0) -> StripPlan:
        """Each disc owns its half of the driving width (left: offsets 0 to w/2, right: -w/2 to 0) out to
        its steps' reach over treated ground (`steps_reach_m`), while its gate is open: the spread
        beyond that is the pattern's designed overlap with the neighbours. Sections (level, side) as
        `deposition`'s, each side's product its disc's."""
        levels, reach_m = self._levels(states)
        count = reach_m.size
        width = np.repeat(np.minimum(reach_m, self.implement.width_m / 2), 2)   # (level, side) pairs
        level = (levels[:, None, :] == np.arange(count)[None, :, None]) & (reach_m > 0)[None, :, None]
        on = np.tile(self.sides_on(states.actual), (1, count)) & level.reshape(len(levels), 2 * count)
        owned = SectionStates(on, width, np.tile(SIDES, count) * width / 2, states.pass_index)
        return _by_side(StripPlan.of(track, owned, delay_s, period_s, cell_m, ticks, tick_m, first_tick,
                                     own_drives=True), count)

    def _levels(self, states: SectionStates) -> tuple[np.ndarray, np.ndarray]:
        """Each side's reach over treated ground per tick as a level (n, 2; int) and each level's reach,
        m: its steps on (`steps_reach_m`), one level (the whole half) where the switch decides on
        whole sides."""
        if states.steps_on is None:
            return np.zeros((len(states.actual), 2), np.int64), np.array([self.spec.half_width_m])
        steps = self.spec.side_steps
        return (np.asarray(states.steps_on, np.int64),
                np.arange(steps + 1) * (self.spec.half_width_m / steps))


@dataclass(frozen=True)
class ThrowPlan:
    """Where a spinner's product lands, before any product: the discs' joined spans (a `StripPlan` of
    the two sides, whose ``mass_kg`` maps each disc's kg to its items) thrown through
    `maps.SpinnerThrow` with each item's side and reach."""

    strips: StripPlan
    side: np.ndarray        # (items,) +1 left disc, -1 right
    reach_m: np.ndarray     # (items,)
    offset_m: np.ndarray    # the transverse pattern's knots
    mass_per_m: np.ndarray
    throw_distance_m: float

    def footprint(self) -> SpinnerThrow:
        """The items as the deposition engine's ``spinner`` footprint."""
        s = self.strips.strips
        return SpinnerThrow(s.x0_m, s.y0_m, s.x1_m, s.y1_m, self.side, self.reach_m, self.offset_m,
                            self.mass_per_m, self.throw_distance_m)

    @property
    def pass_index(self) -> np.ndarray:
        """The pass of each item, shape (items,)."""
        return self.strips.pass_index

    def mass_kg(self, drive_kg) -> np.ndarray:
        """Each item's kg from each disc's per tick (ticks, 2[, m]): `StripPlan.mass_kg`."""
        return self.strips.mass_kg(drive_kg)


def _by_side(spans: StripPlan, levels: int) -> StripPlan:
    """`spans` of virtual sections (level, side) (section ``2 * level + side``, per tick) as the plan of
    the two sides' drives: its items keep their virtual section (the level and the side), their
    product is their side's disc's."""
    from scipy import sparse

    m = spans.to_strips
    # An item is one virtual section's: its columns (tick, virtual section) become (tick, side), still in
    # time order, as many and in the same order (the sums of `StripPlan.mass_kg` alike).
    tick, virtual = np.divmod(m.indices, 2 * levels)
    to_sides = sparse.csr_matrix((m.data, tick * 2 + virtual % 2, m.indptr),
                                 shape=(m.shape[0], spans.ticks.size * 2))
    # A side's drive is open where any of its levels is (an OR level by level: `any` over the middle axis
    # of (ticks, levels, 2) takes ten times as long).
    drive_open = spans.drive_open[:, :2].copy()
    for level in range(1, levels):
        drive_open |= spans.drive_open[:, 2 * level:2 * level + 2]
    return dataclasses.replace(spans, to_strips=to_sides, drive_open=drive_open)


def _room_m(polygon, x_m, y_m, ux, uy) -> np.ndarray:
    """The distance (m) from each point (x_m, y_m) to the boundary of `polygon` along the unit
    direction (ux, uy) (column 0) and against it (column 1), shape (n, 2): 0 for a point outside, inf
    where the ray meets no boundary. Ray casting against the boundary's segments in numpy, in chunks
    of points (a point is inside where its ray crosses the boundary an odd number of times)."""
    import shapely

    rings = [shapely.get_coordinates(part) for part in shapely.get_parts(polygon.boundary)]
    a = np.concatenate([r[:-1] for r in rings])
    e = np.concatenate([np.diff(r, axis=0) for r in rings])
    x, y, ux, uy = (np.asarray(v, float) for v in (x_m, y_m, ux, uy))
    room = np.empty((x.size, 2))
    step = max(1, ROOM_CHUNK // max(len(a), 1))
    for lo in range(0, x.size, step):
        part = slice(lo, lo + step)
        dx, dy = a[None, :, 0] - x[part, None], a[None, :, 1] - y[part, None]
        cross = ux[part, None] * e[None, :, 1] - uy[part, None] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (dx * e[None, :, 1] - dy * e[None, :, 0]) / cross
            s = (dx * uy[part, None] - dy * ux[part, None]) / cross
        hit = (cross != 0) & (s >= 0) & (s < 1)   # half-open: a vertex is crossed once
        ahead, behind = hit & (t >= 0), hit & (t < 0)
        inside = ahead.sum(axis=1) % 2 == 1
        room[part, 0] = np.where(ahead, t, np.inf).min(axis=1)
        room[part, 1] = np.where(behind, -t, np.inf).min(axis=1)
        room[part][~inside] = 0.0
    return room
