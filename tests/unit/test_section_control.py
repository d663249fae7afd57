"""Section control (services.sim.sections) and per-section landing (services.sim.section_landing)
on tracks sampled from the real coverage planner: no SUMO, the same geometry."""

import dataclasses
import functools

import numpy as np
import pytest
import shapely
from affine import Affine

from vrsim.maps import AsApplied, Grid, synthetic
from vrsim.services.sim.metrics import overlap_metrics
from vrsim.services.sim.section_landing import section_strips, worked_fraction
from vrsim.services.sim.sections import (
    SWITCHING,
    SectionStates,
    SectionSwitch,
    command,
    gate,
    pass_index,
    switch_sections,
)
from vrsim.vehicle import Field, Implement, plan_coverage
from vrsim.vehicle.implement import SECTION_CONTROL_MODES

PERIOD_S = 0.05
RATE_KG_HA = 150.0
MAP_CELL_M = 2.0
DEFAULT_POLYGON = [[10.5, 52.1], [10.5089204, 52.0998203], [10.5095054, 52.101617], [10.5081893, 52.1032339],
                   [10.5043871, 52.1029644], [10.5005849, 52.1033238], [10.4997075, 52.1017068]]


@functools.cache
def rectangle():
    return Field.rectangle(160.0, 250.0, lat=48.2, lon=11.6)


@functools.cache
def planned_path(field, width_m=12.0, heading_deg=None):
    return plan_coverage(field, width_m, headland_passes=1, heading_deg=heading_deg)


@functools.cache
def planned_track(field, width_m=12.0, heading_deg=None, speed_m_s=2.5, speed_wave=0.0):
    """The planner's path driven at `speed_m_s`, varied by +-`speed_wave` over a 15 s period."""
    path = planned_path(field, width_m, heading_deg)
    t = np.arange(0.0, 2.0 * path.length_m / speed_m_s, PERIOD_S)
    v = speed_m_s * (1.0 + speed_wave * np.sin(2.0 * np.pi * t / 15.0))
    s = np.concatenate(([0.0], np.cumsum(v[:-1] * PERIOD_S)))
    keep = s < path.length_m
    x, y, h, _, on = path.locate(s[keep])
    return {"time_s": t[keep], "x_m": x, "y_m": y, "heading_rad": h, "speed_m_s": v[keep], "implement_on": on,
            "s_m": s[keep]}


def apply(field, track, implement, heading_deg=None):
    """Switch, meter ideally (the target rate exactly for the width on) and land: the as-applied
    raster, the overlap figures and the states."""
    path = planned_path(field, implement.width_m, heading_deg)
    states = switch_sections(track, implement, field.polygon, path, MAP_CELL_M)
    metered = RATE_KG_HA * track["speed_m_s"] * states.width_on_m * PERIOD_S / 1e4
    grid = grid_for(field)
    applied = AsApplied(grid)
    section_strips(track, metered, states, implement.delivery_delay_s, PERIOD_S, MAP_CELL_M).add_to(applied)
    worked = worked_fraction(track, implement.width_m, grid)
    xs, ys = grid.cell_centres()
    in_field = shapely.contains_xy(field.polygon, *np.meshgrid(xs, ys))
    figures = overlap_metrics(applied.coverage_fraction, applied.overlap_fraction, applied.overlap_kg, worked,
                              in_field, grid.rates_kg_ha)
    return applied, figures, states, in_field


def test_registry_covers_the_modes():
    assert set(SWITCHING) == set(SECTION_CONTROL_MODES)


# ---------------------------------------------------------------------- boundary and off
def test_boundary_mode_is_the_centre_in_field_rule():
    field = Field.from_lonlat(DEFAULT_POLYGON)
    track = planned_track(field, speed_wave=0.05)
    rng = np.random.default_rng(1)
    n = track["time_s"].size
    measured = (track["x_m"] + rng.normal(0, 0.05, n), track["y_m"] + rng.normal(0, 0.05, n),
                track["speed_m_s"] * 1.01)
    imp = Implement(section_control="boundary")
    # GNSS 3 m off to the east (and noisy): the outer sections seem outside on the east edges.
    measured = (measured[0] + 3.0, measured[1], measured[2])
    states = switch_sections(track, imp, field.polygon, None, MAP_CELL_M, measured)
    # Before coverage control: the landing point predicted from the measured fix, speed, acceleration
    # and yaw rate (`Motion.ahead`, tested in test_look_ahead_motion), and a section on while the
    # implement is on and its centre there lies inside the field.
    motion = states.motion
    np.testing.assert_array_equal(motion.x_m, measured[0])
    lx, ly, cos, sin = motion.ahead(imp.delivery_delay_s)
    expected = imp.sections_on(field.polygon, lx, ly, np.arctan2(sin, cos), track["implement_on"])
    assert np.array_equal(states.actual, expected) and np.array_equal(states.commanded, expected)
    np.testing.assert_array_equal(states.width_on_m, expected.sum(axis=1) * imp.section_width_m)
    working = track["implement_on"]
    partly = working & (states.count_on > 0) & (states.count_on < imp.sections)
    assert partly.sum() > 100  # sections do cross this field's boundary


def test_off_mode_keeps_all_sections_on_while_working():
    track = planned_track(rectangle())
    states = switch_sections(track, Implement(section_control="off"), rectangle().polygon, None, MAP_CELL_M)
    assert np.array_equal(states.actual, np.repeat(track["implement_on"][:, None], 6, axis=1))


# ---------------------------------------------------------------------- coverage
@pytest.mark.parametrize("heading_deg", [None, 35.0])
def test_coverage_mode_switches_sections_off_over_the_headland(heading_deg):
    field = rectangle()
    track = planned_track(field, heading_deg=heading_deg)
    applied, cover, states, in_field = apply(field, track, Implement(section_control="coverage"), heading_deg)
    _, bound, bstates, _ = apply(field, track, Implement(section_control="boundary"), heading_deg)
    assert cover.overlap_area_pct < 1.0 and cover.overlap_area_pct < 0.1 * bound.overlap_area_pct
    assert cover.overlap_kg < 0.1 * bound.overlap_kg
    assert cover.skip_area_pct < 1.0
    # Coverage switching turns sections off (one by one where swaths meet the headland obliquely).
    assert states.actual.sum() < 0.97 * bstates.actual.sum()
    if heading_deg is not None:
        working = track["implement_on"]
        assert (working & (states.count_on > 0) & (states.count_on < 6)).sum() > 500
    else:  # square swath ends: the ideal meter applies the map on nearly all the covered area
        covered = in_field & (applied.coverage_fraction >= 0.9)
        rel = np.abs(applied.applied_kg_ha[covered] - RATE_KG_HA) / RATE_KG_HA
        assert (rel <= 0.10).mean() >= 0.99


def test_longer_latencies_give_more_overlap_and_skips():
    field = rectangle()
    # Speed varying by +-20 % makes the prediction over the look-ahead err, as in the field.
    track = planned_track(field, heading_deg=35.0, speed_wave=0.2)
    figures = []
    for delay_s in (0.5, 1.0, 2.0, 4.0):
        imp = Implement(section_on_delay_s=delay_s, section_off_delay_s=delay_s)
        figures.append(apply(field, track, imp, 35.0)[1])
    overlap = [f.overlap_area_pct for f in figures]
    skip = [f.skip_area_pct for f in figures]
    assert np.all(np.diff(overlap) > 0), overlap
    assert np.all(np.diff(skip) > 0), skip


@pytest.mark.parametrize("on_s, off_s", [(1.0, 0.6), (0.3, 2.0), (0.93, 0.37)])
def test_gates_follow_commands_after_the_latencies(on_s, off_s):
    field = rectangle()
    track = planned_track(field, heading_deg=35.0)
    imp = Implement(section_on_delay_s=on_s, section_off_delay_s=off_s)
    states = switch_sections(track, imp, field.polygon, planned_path(field, 12.0, 35.0), MAP_CELL_M)
    # Changes per tick (+1 on, -1 off), everything off before the first tick.
    dc = np.diff(states.commanded.astype(np.int8), axis=0, prepend=0)
    dg = np.diff(states.actual.astype(np.int8), axis=0, prepend=0)
    for s in range(imp.sections):
        for delay_s, edge in ((on_s, 1), (off_s, -1)):
            ticks = np.flatnonzero(dg[:, s] == edge)
            assert ticks.size >= 10
            k = round(delay_s / PERIOD_S)
            assert abs(k * PERIOD_S - delay_s) <= PERIOD_S  # within a tick of the configured latency
            # The gate switched exactly k ticks after the command did.
            assert (dc[ticks - k, s] == edge).all()


@pytest.mark.parametrize("k_on, k_off", [(5, 2), (2, 5), (3, 3)])
def test_commands_land_product_where_wanted(k_on, k_off):
    k_delivery = 3
    wanted = np.zeros(200, bool)
    wanted[20:60] = wanted[62:100] = True  # a 2-tick gap
    wanted[140:142] = True  # a 2-tick island
    wanted[160:175] = True
    ahead = np.concatenate((wanted, np.zeros(20, bool)))[:, None]
    w_on = ahead[k_delivery + k_on: k_delivery + k_on + 200]
    w_off = ahead[k_delivery + k_off: k_delivery + k_off + 200]
    cmd = command(w_on, w_off, k_on >= k_off, np.zeros(1, bool))
    landed = np.concatenate((np.zeros((k_delivery, 1), bool), gate(cmd, k_on, k_off)[:-k_delivery]))[:, 0]
    expected = wanted.copy()
    if k_on != k_off:
        # Shorter than the delays' difference (3 ticks): the section cannot stop and restart, or
        # start and stop, in time: the gap is bridged, the island skipped.
        expected[60:62] = True
        expected[140:142] = False
    assert np.array_equal(landed, expected)


def test_passes_cut_turns_and_half_circles():
    track = planned_track(rectangle())
    passes = pass_index(track["heading_rad"], track["implement_on"])
    assert np.array_equal(passes < 0, ~track["implement_on"])
    heading = np.unwrap(track["heading_rad"])
    for p in range(passes.max() + 1):
        turned = heading[passes == p] - heading[passes == p][0]
        assert np.abs(turned).max() < np.pi
    # The headland loop (a full turn) is two passes; then one pass per swath.
    runs = np.count_nonzero(np.diff(track["implement_on"].astype(int)) == 1) + 1
    assert passes.max() + 1 == runs + 1


def test_no_work_no_sections():
    track = dict(planned_track(rectangle()))
    track["implement_on"] = np.zeros(track["time_s"].size, bool)
    # Coverage control reads the plan: beyond its end nothing is to be worked.
    track["s_m"] = np.full(track["time_s"].size, planned_path(rectangle()).length_m)
    for mode in SECTION_CONTROL_MODES:
        states = switch_sections(track, Implement(section_control=mode), rectangle().polygon,
                                 planned_path(rectangle()), MAP_CELL_M)
        assert not states.actual.any() and not states.commanded.any()


@pytest.mark.parametrize("mode", SECTION_CONTROL_MODES)
def test_batches_give_the_states_of_one_step(mode):
    """The controller service steps the switch once per lockstep batch (one tick in real-time mode);
    `vrsim run` once over the whole track: the same states, exactly."""
    field = rectangle()
    track = planned_track(field, heading_deg=35.0, speed_wave=0.2)
    path = planned_path(field, 12.0, 35.0)
    imp = Implement(section_control=mode, section_on_delay_s=0.7, section_off_delay_s=1.3)
    whole = switch_sections(track, imp, field.polygon, path, MAP_CELL_M, period_s=PERIOD_S)
    switch = SectionSwitch(imp, field.polygon, path, PERIOD_S, MAP_CELL_M)
    n = track["time_s"].size
    sizes = np.random.default_rng(4).integers(1, 700, n)
    sizes[:300] = 1
    cuts = np.cumsum(sizes)
    parts = [switch.step(*(track[k][part] for k in ("x_m", "y_m", "heading_rad", "speed_m_s", "implement_on",
                                                   "s_m")))
             for part in np.split(np.arange(n), cuts[cuts < n])]
    assert len(parts) > 300
    for name in ("actual", "commanded", "pass_index"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name))
    assert whole.actual.any() and not whole.actual.all()


# ---------------------------------------------------------------------- per-section landing
def straight_track(n=2000, speed_m_s=2.5):
    """Eastwards along y = 5 300 050, on cell edges of a 1 m grid."""
    t = np.arange(n) * PERIOD_S
    return {"time_s": t, "x_m": 500_010.0 + speed_m_s * t, "y_m": np.full(n, 5_300_050.0),
            "heading_rad": np.zeros(n), "speed_m_s": np.full(n, speed_m_s), "implement_on": np.ones(n, bool)}


def grid_1m():
    return synthetic.uniform((500_000.0, 5_300_000.0, 500_300.0, 5_300_100.0), "EPSG:32632", cell_size_m=1.0,
                             rate_kg_ha=0.0)


def test_unequal_sections_land_their_share_on_their_own_strip():
    imp = Implement(width_m=12.0, section_widths_m=[2.0, 4.0, 6.0])  # left (north) to right
    track = straight_track()
    n = track["time_s"].size
    actual = np.repeat(np.array([[True, False, True]]), n, axis=0)
    states = SectionStates(actual, imp.section_widths, imp.section_offsets_m, np.zeros(n, np.int64))
    metered = np.full(n, 0.01)
    strips = section_strips(track, metered, states, imp.delivery_delay_s, PERIOD_S, 1.0)
    acc = AsApplied(grid_1m())
    strips.add_to(acc)
    kg = acc.applied_kg.sum(axis=1)  # per row; row r spans y 5 300 100 - r - 1 .. 5 300 100 - r
    total = metered.sum()
    # Section 0 (2 m) over y +4..+6 -> rows 44-45; section 1 (off) rows 46-49; section 2 (6 m) rows 50-55.
    assert kg[44:46].sum() == pytest.approx(total * 2 / 8, rel=1e-9)
    assert kg[46:50].sum() == 0.0
    assert kg[50:56].sum() == pytest.approx(total * 6 / 8, rel=1e-9)
    assert kg[:44].sum() == 0.0 and kg[56:].sum() == 0.0
    # The same rate on both strips: the meter's product shared by width.
    rate = acc.applied_kg_ha[:, 30:200]
    np.testing.assert_allclose(rate[44:46], rate[50:56].mean(), rtol=1e-9)
    assert set(np.unique(strips.section)) == {0, 2}


def test_sections_all_on_land_as_one_full_width_strip():
    imp = Implement(width_m=12.0, sections=6, section_control="off")
    track = straight_track()
    states = switch_sections(track, imp, shapely.box(500_000, 5_300_000, 500_300, 5_300_100), None, 1.0)
    metered = np.random.default_rng(2).uniform(0.005, 0.015, track["time_s"].size)
    metered[-20:] = 0.0  # would land beyond the track's end
    per_section = AsApplied(grid_1m())
    section_strips(track, metered, states, imp.delivery_delay_s, PERIOD_S, 1.0).add_to(per_section)
    whole = AsApplied(grid_1m())
    t0 = track["time_s"] + imp.delivery_delay_s
    x0 = np.interp(t0, track["time_s"], track["x_m"])
    x1 = np.interp(t0 + PERIOD_S, track["time_s"], track["x_m"])
    whole.add_strips(x0, 5_300_050.0, x1, 5_300_050.0, 12.0, metered)
    np.testing.assert_allclose(per_section.applied_kg, whole.applied_kg, rtol=1e-9, atol=1e-12)
    assert per_section.outside_kg == pytest.approx(whole.outside_kg)


def test_overlap_and_skip_figures():
    grid = synthetic.uniform((0.0, 0.0, 100.0, 100.0), "EPSG:32632", cell_size_m=5.0, rate_kg_ha=0.0)
    applied, worked = AsApplied(grid), AsApplied(grid)
    # Pass 0 covers x 0-40, pass 1 x 30-70 at 100 kg/ha; the plan meant to work x 0-80.
    applied.add_strips(20.0, 0.0, 20.0, 100.0, 40.0, 40.0, pass_index=0)
    applied.add_strips(50.0, 0.0, 50.0, 100.0, 40.0, 40.0, pass_index=1)
    worked.add_strips(40.0, 0.0, 40.0, 100.0, 80.0, 1.0)
    figures = overlap_metrics(applied.coverage_fraction, applied.overlap_fraction, applied.overlap_kg,
                              worked.coverage_fraction, np.ones((20, 20), bool), np.full((20, 20), 100.0))
    assert figures.overlap_area_pct == pytest.approx(100 * 10 / 70)  # of the 70 m covered, 10 m twice
    assert figures.skip_area_pct == pytest.approx(100 * 10 / 80)  # x 70-80 worked but bare
    assert figures.overlap_kg == pytest.approx(10.0)  # 10 m x 100 m at 100 kg/ha from the second pass


def test_landing_follows_the_delay_and_passes():
    field = rectangle()
    track = planned_track(field)
    imp = dataclasses.replace(Implement(), section_control="off")
    states = switch_sections(track, imp, field.polygon, None, MAP_CELL_M)
    metered = np.where(states.width_on_m > 0, 0.01, 0.0)
    strips = section_strips(track, metered, states, imp.delivery_delay_s, PERIOD_S, MAP_CELL_M)
    assert strips.mass_kg.sum() == pytest.approx(metered.sum())
    assert np.all(np.diff(strips.pass_index) >= 0) and strips.pass_index.max() == states.pass_index.max()
    # Strips join up to half a cell of travel.
    length = np.hypot(strips.x1_m - strips.x0_m, strips.y1_m - strips.y0_m)
    assert np.median(length) == pytest.approx(0.5 * MAP_CELL_M, rel=0.1) and length.max() < 2 * MAP_CELL_M


def test_worked_fraction_is_the_working_width_along_working_stretches():
    track = dict(straight_track())  # x 500 010 -> ~500 260 at y 5 300 050, width 12: rows 44-55
    track["implement_on"] = track["time_s"] < 40.0  # working for the first 100 m only
    worked = worked_fraction(track, 12.0, grid_1m())
    assert (worked[44:56, 10:110] == 1.0).all()
    assert worked[:44].max() == 0.0 and worked[56:].max() == 0.0 and worked[:, 111:].max() == 0.0
    assert worked.sum() == pytest.approx(12 * 100, rel=1e-3)
    # Cells 2 m tall and 1 m wide: the same area, counted on a grid stretched to square cells.
    tall = Grid(np.zeros((50, 300)), Affine(1.0, 0, 500_000.0, 0, -2.0, 5_300_100.0), "EPSG:32632")
    worked_tall = worked_fraction(track, 12.0, tall)
    assert (worked_tall[22:28, 10:110] == 1.0).all()
    assert worked_tall.sum() * 2 == pytest.approx(1200, rel=1e-3)


def test_strips_of_some_ticks_only():
    """`ticks` lands only those ticks (the machine-limited ones, say), each section's share as before."""
    field = rectangle()
    track = planned_track(field)
    imp = Implement(section_control="boundary")
    states = switch_sections(track, imp, field.polygon, None, MAP_CELL_M)
    metered = np.where(states.width_on_m > 0, 0.01, 0.0)
    every = section_strips(track, metered, states, imp.delivery_delay_s, PERIOD_S, MAP_CELL_M)
    same = section_strips(track, metered, states, imp.delivery_delay_s, PERIOD_S, MAP_CELL_M,
                          ticks=np.arange(track["time_s"].size))
    for name in ("x0_m", "y0_m", "x1_m", "y1_m", "mass_kg", "pass_index", "section"):
        np.testing.assert_array_equal(getattr(same, name), getattr(every, name))
    ticks = np.flatnonzero((np.arange(track["time_s"].size) // 500) % 3 == 0)
    some = section_strips(track, metered, states, imp.delivery_delay_s, PERIOD_S, MAP_CELL_M, ticks=ticks)
    assert some.mass_kg.sum() == pytest.approx(metered[ticks].sum(), rel=1e-12)
    alone, rest = AsApplied(grid_for(field)), AsApplied(grid_for(field))
    some.add_to(alone)
    every.add_to(rest)
    assert 0.25 < alone.coverage_fraction.sum() / rest.coverage_fraction.sum() < 0.42


def grid_for(field):
    minx, miny, maxx, maxy = field.polygon.bounds
    return synthetic.uniform((minx - 20, miny - 20, maxx + 20, maxy + 20), field.crs, cell_size_m=MAP_CELL_M,
                             rate_kg_ha=RATE_KG_HA)


def test_product_with_every_gate_closed_is_refused():
    imp = Implement(section_control="off")
    track = dict(straight_track(100))
    track["implement_on"] = np.arange(100) < 50
    states = switch_sections(track, imp, shapely.box(500_000, 5_300_000, 500_300, 5_300_100), None, 1.0)
    with pytest.raises(ValueError, match="tick 50 meters product with every gate closed"):
        section_strips(track, np.full(100, 0.01), states, imp.delivery_delay_s, PERIOD_S, 1.0)


@pytest.mark.parametrize("on_s, off_s", [(1.0, 0.6), (0.3, 2.0)])
def test_the_second_look_ahead_read_where_it_decides_gives_the_commands_of_both_read_everywhere(
        on_s, off_s, monkeypatch):
    from vrsim.services.sim.sections import switching

    field = rectangle()
    track = planned_track(field, heading_deg=35.0, speed_wave=0.2)
    imp = Implement(section_on_delay_s=on_s, section_off_delay_s=off_s)
    path = planned_path(field, imp.width_m, 35.0)
    states = switch_sections(track, imp, field.polygon, path, MAP_CELL_M)

    def both_everywhere(self, motion, s_m, moving, a, b):
        return tuple(self._wanted(*self._ahead(motion, s_m, lead_s, slice(a, b)), 0, b - a) & moving[a:b]
                     for lead_s in (self.lead_on_s, self.lead_off_s))

    monkeypatch.setattr(switching._Coverage, "_both_wanted", both_everywhere)
    plain = switch_sections(track, imp, field.polygon, path, MAP_CELL_M)
    assert plain.commanded.any() and not plain.commanded.all()
    np.testing.assert_array_equal(states.commanded, plain.commanded)
    np.testing.assert_array_equal(states.actual, plain.actual)
