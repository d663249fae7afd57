"""A spinner's sides shortened in steps over treated ground (services/sim/sections/switching.py's
stepped coverage switch, services/sim/machines/spinner.py): the switch decides each side's steps in
stage 1, in batches of any size with the same result; a shortened side meters its pattern's share
within its reach and throws it there."""

import dataclasses
import functools
import json

import numpy as np
import pytest

from vrsim.maps import AsApplied, synthetic
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.sections import SectionStates, SectionSwitch, switch_sections
from vrsim.services.sim.sections.motion import MotionTrend
from vrsim.vehicle import Field, Implement, plan_coverage
from vrsim.vehicle.spinner import SpinnerSpec

PERIOD_S = 0.05
MAP_CELL_M = 2.0
KEYS = ("x_m", "y_m", "heading_rad", "speed_m_s", "implement_on", "s_m")


def _spinner(side_steps=4, sections=2):
    return Implement(kind="spinner", width_m=24.0, sections=sections, section_on_delay_s=0.4,
                     section_off_delay_s=0.6, machine=SpinnerSpec(spread_width_m=36.0, side_steps=side_steps))


@functools.cache
def _field_and_path():
    """88 m wide at 24 m: the two passes between the headlands (40 m) overlap by 8 m."""
    field = Field.rectangle(88.0, 160.0, lat=48.2, lon=11.6)
    return field, plan_coverage(field, 24.0, headland_passes=1, heading_deg=0.0)


@functools.cache
def _track():
    _, path = _field_and_path()
    s = np.arange(0.0, path.length_m, 3.0 * PERIOD_S)
    x, y, h, _, on = path.locate(s)
    return {"time_s": np.arange(s.size) * PERIOD_S, "x_m": x, "y_m": y, "heading_rad": h,
            "speed_m_s": np.full(s.size, 3.0), "implement_on": on, "s_m": s}


def _switch(implement, side_steps):
    field, path = _field_and_path()
    return SectionSwitch(implement, field.polygon, path, PERIOD_S, MAP_CELL_M, side_steps)


def test_a_side_over_a_treated_strip_keeps_the_steps_that_fit_and_one_step_is_on_or_off():
    track = _track()
    stepped = _switch(_spinner(), 4).step(*(track[k] for k in KEYS))
    on_off = _switch(_spinner(side_steps=1), 1).step(*(track[k] for k in KEYS))
    assert on_off.steps_on is None
    steps = stepped.steps_on
    assert steps.shape == (track["x_m"].size, 2) and steps.max() == 4
    np.testing.assert_array_equal(stepped.actual, steps > 0)   # a side is on where a step is
    shortened = (steps > 0) & (steps < 4)
    # In the headland pass's corners (and 2 s either side) the inner side's outer bands pivot or move
    # backwards at this constant 3 m/s, and the slow speed cutoff closes them: a side shortened there
    # for its bands' own speed, where on/off (one section per side, at its centre) may keep it on.
    turned = np.r_[np.abs(np.diff(np.unwrap(track["heading_rad"]))) > 1e-9, False]
    turning = (np.convolve(turned, np.ones(81), "same") > 0)[:, None]
    assert (shortened & turning).sum() > 100
    straight = shortened & ~turning
    assert straight.sum() > 100   # the overlapping pass: a side shortened where on/off shut it
    assert (straight & ~on_off.actual).sum() > 0.9 * straight.sum()
    # Where the whole side fits, its strip is the side's: on as the on/off switch has it.
    full = steps == 4
    assert np.mean(on_off.actual[full]) > 0.99


def test_one_section_switches_both_sides_and_each_keeps_its_own_steps():
    track = _track()
    states = _switch(_spinner(sections=1), 4).step(*(track[k] for k in KEYS))
    assert states.actual.shape[1] == 1
    np.testing.assert_array_equal(states.actual[:, 0], (states.steps_on > 0).any(axis=1))
    assert (states.steps_on[:, 0] != states.steps_on[:, 1]).any()


def test_batches_and_a_state_carried_through_json_give_the_steps_of_one_step():
    track, imp = _track(), _spinner()
    field, path = _field_and_path()
    whole = switch_sections(track, imp, field.polygon, path, MAP_CELL_M, period_s=PERIOD_S)
    assert whole.steps_on is None   # without the machine's steps: on or off, as before
    whole = _switch(imp, 4).step(*(track[k] for k in KEYS))
    n = track["x_m"].size
    cuts = np.cumsum(np.random.default_rng(3).integers(1, 900, n))
    cuts = cuts[cuts < n]
    switch, parts = _switch(imp, 4), []
    for i, part in enumerate(np.split(np.arange(n), cuts)):
        if i % 3 == 2:   # the controller service carries the state as plain data
            state = json.loads(json.dumps(switch.state()))
            switch = _switch(imp, 4)
            switch.set_state(state)
        parts.append(switch.step(*(track[k][part] for k in KEYS)))
    for name in ("actual", "commanded", "steps_on"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name))


def _straight(n=400, speed_m_s=3.0):
    t = np.arange(n) * PERIOD_S
    return {"time_s": t, "x_m": 500_010.0 + speed_m_s * t, "y_m": np.full(n, 5_300_050.0),
            "heading_rad": np.zeros(n), "speed_m_s": np.full(n, speed_m_s), "implement_on": np.ones(n, bool)}


def test_a_shortened_side_meters_its_patterns_share_within_its_reach_and_throws_it_there():
    imp = Implement(kind="spinner", width_m=24.0, sections=2, shaft_rpm_max=1e6,
                    machine=SpinnerSpec(spread_width_m=36.0, side_steps=4, throw_distance_m=0.0))
    machine, track = machine_for(imp), _straight()
    n = track["x_m"].size
    steps = np.tile([1, 4], (n, 1))   # the left side one step of four (4.5 m), the right whole
    motion = MotionTrend(PERIOD_S).step(track["x_m"], track["y_m"], track["heading_rad"], track["speed_m_s"])
    states = SectionStates(np.ones((n, 2), bool), imp.section_widths, imp.section_offsets_m, np.zeros(n, int),
                           motion=motion, steps_on=steps)
    rate = np.full((n, 2), 200.0)
    target = machine.drive_targets(rate, states)
    full = machine.drive_targets(rate, dataclasses.replace(states, steps_on=None))
    np.testing.assert_allclose(target[:, 1], full[:, 1])
    np.testing.assert_allclose(target[:, 0] / full[:, 0], 1 - (1 - 4.5 / 18.0) ** 2)   # the triangle's share
    plan = machine.deposition(track, states, 0.0, PERIOD_S, 1.0)
    grid = synthetic.uniform((500_000.0, 5_300_000.0, 500_100.0, 5_300_100.0), "EPSG:32632", cell_size_m=1.0,
                             rate_kg_ha=0.0)
    applied = AsApplied(grid)
    drive_kg = np.tile([0.01, 0.02], (n, 1))
    applied.deposit(plan.footprint(), plan.mass_kg(drive_kg), pass_index=plan.pass_index)
    x, y = grid.cell_centres()
    along = applied.applied_kg_ha[:, (x > 500_020.0) & (x < 500_040.0)]   # rows north to south
    left, right = along[(y > 5_300_055.0) & (y < 5_300_080.0)], along[(y < 5_300_045.0) & (y > 5_300_020.0)]
    assert left.max() == 0.0 and right[:8].min() > 0.0   # the left side's 4.5 m, the right side's 18
    total = applied.applied_kg_ha.sum() * grid.cell_area_m2 / 1e4 + applied.outside_kg
    assert total == pytest.approx(drive_kg.sum(), rel=1e-9)


def _reach_by_side(steps, counts, treated, outside, treated_pct, outside_pct):
    """The stepped switch's decision side by side, band by band, in integers: a side's reach is the
    most bands from the centre line out whose points fit both limits; the bands within it wanted."""
    m, wanted = treated.shape[0], np.zeros(treated.shape, bool)
    for side in (range(steps - 1, -1, -1), range(steps, 2 * steps)):   # each side's bands, centre line out
        bands = list(side)
        for row in range(m):
            reach = 0
            for k in range(1, steps + 1):
                strip = bands[:k]
                total = int(counts[strip].sum())
                if (100 * int(treated[row, strip].sum()) <= treated_pct * total
                        and 100 * int(outside[row, strip].sum()) <= outside_pct * total):
                    reach = k
            wanted[row, bands[:reach]] = True
    return wanted


@pytest.mark.parametrize("steps", [1, 2, 4, 16])
def test_the_bands_wanted_and_the_steps_on_are_those_counted_band_by_band(steps):
    from vrsim.services.sim.sections.switching import _BandReach

    rng = np.random.default_rng(steps)
    counts = rng.integers(4, 40, 2 * steps)
    m = 300
    treated = rng.integers(0, counts + 1, (m, 2 * steps)) * (rng.random((m, 2 * steps)) < 0.6)
    outside = rng.integers(0, counts + 1, (m, 2 * steps)) * (rng.random((m, 2 * steps)) < 0.2)
    for treated_pct, outside_pct in ((50.0, 50.0), (10.0, 0.0), (33.3, 100.0)):
        reach = _BandReach(steps, counts, treated_pct, outside_pct)
        wanted = reach.wanted(treated.astype(np.int32), outside.astype(np.int32))
        expected = _reach_by_side(steps, counts, treated, outside, treated_pct, outside_pct)
        np.testing.assert_array_equal(wanted, expected)
        assert 0 < wanted.mean() < 1
    gates = rng.random((m, 2 * steps)) < 0.8
    on = reach.steps_on(gates)
    for side, bands in enumerate((gates[:, steps - 1::-1], gates[:, steps:])):
        leading = np.array([next((k for k in range(steps) if not row[k]), steps) for row in bands])
        np.testing.assert_array_equal(on[:, side], leading)
    assert on.dtype == np.int64


@pytest.mark.parametrize("border_spreading", [True, False])
def test_the_reach_far_from_the_boundary_is_the_full_reach_the_ray_cast_gives(border_spreading):
    import shapely

    from vrsim.services.sim.machines.spinner import _room_m

    # An L with a hole: reflex corners, whose erosion is rounded.
    field = shapely.Polygon([(0, 0), (300, 0), (300, 120), (110, 120), (110, 250), (0, 250)],
                            holes=[[(40, 40), (70, 40), (70, 70), (40, 70)]])
    imp = Implement(kind="spinner", width_m=24.0, sections=2,
                    machine=SpinnerSpec(spread_width_m=36.0, border_spreading=border_spreading))
    machine = machine_for(imp, field)
    rng = np.random.default_rng(5)
    x, y, h = rng.uniform(-20, 320, 40_000), rng.uniform(-20, 270, 40_000), rng.uniform(-4, 4, 40_000)
    reach = machine.reach_m(x, y, np.cos(h), np.sin(h))
    ray_cast = imp.machine.side_reach_m(_room_m(field, x, y, -np.sin(h), np.cos(h)))
    np.testing.assert_array_equal(reach, ray_cast)
    far = (reach == 18.0).all(axis=1)
    assert 0.2 < far.mean() < 0.8 and (reach == 0.0).any() and ((reach > 0) & (reach < 18.0)).any()
