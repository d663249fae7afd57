import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from vrsim.services.sim.metrics import (
    METRICS,
    LimitMetrics,
    MapMetrics,
    OverlapMetrics,
    map_metrics,
    overlap_metrics,
    summary,
    within_band,
)
from vrsim.services.sim.transitions import (
    EVENTS,
    EventFigures,
    TransitionEvents,
    TransitionMetrics,
    rate_steps,
    transition_events,
    transitions,
)
from vrsim.vehicle import Implement


def _grid(rows=10, cols=10, rate=100.0):
    rx = np.full((rows, cols), rate)
    field = np.ones((rows, cols), bool)
    cover = np.ones((rows, cols))
    return rx, field, cover


def test_constant_error_gives_known_mae_rmse_bias():
    rx, field, cover = _grid()
    applied = rx + 4.0  # +4 % everywhere
    cell_ha = 0.01
    m = map_metrics(rx, applied, cover, field, cell_ha, applied_total_kg=applied.sum() * cell_ha,
                    worked_fraction=cover)
    assert m.mae_kg_ha == pytest.approx(4.0)
    assert m.rmse_kg_ha == pytest.approx(4.0)
    assert m.bias_kg_ha == pytest.approx(4.0)
    assert m.mae_pct == pytest.approx(4.0)
    assert m.within_5pct_area_pct == 100.0
    assert m.within_10pct_area_pct == 100.0
    assert m.prescribed_kg == pytest.approx(100 * 100 * cell_ha)
    assert m.mass_balance_pct == pytest.approx(4.0)
    assert m.coverage_pct == 100.0
    assert m.off_target_kg == 0.0


def test_mixed_error_shares_and_signs():
    rx, field, cover = _grid()
    applied = rx.copy()
    applied[:5] += 8.0  # half the area +8 %
    applied[5:] -= 2.0  # half -2 %
    m = map_metrics(rx, applied, cover, field, 0.01, applied_total_kg=applied.sum() * 0.01,
                    worked_fraction=cover)
    assert m.mae_kg_ha == pytest.approx(5.0)
    assert m.rmse_kg_ha == pytest.approx(np.sqrt((64 + 4) / 2))
    assert m.bias_kg_ha == pytest.approx(3.0)
    assert m.within_5pct_area_pct == pytest.approx(50.0)
    assert m.within_10pct_area_pct == pytest.approx(100.0)


def test_uncovered_cells_and_off_target():
    rx, field, cover = _grid()
    field[:, -1] = False  # last column outside the field
    cover[0, 0] = 0.5  # partly covered: left out of the error figures
    rx[1, 1] = 0.0  # a zero-rate cell that still got product
    applied = rx.copy()
    applied[1, 1] = 50.0
    applied[:, -1] = 20.0
    m = map_metrics(rx, applied, cover, field, 0.01, applied_total_kg=applied.sum() * 0.01,
                    off_grid_kg=1.5, worked_fraction=cover)
    assert m.covered_cells == 10 * 9 - 1
    assert m.coverage_pct == pytest.approx(100 * 89 / 90)
    assert m.off_target_kg == pytest.approx(10 * 20 * 0.01 + 50 * 0.01 + 1.5)


def test_rate_steps_detects_only_big_changes():
    rx = np.array([100, 100, 104, 104, 150, 150, 150, 50, 50])
    on = np.ones(rx.size, bool)
    assert list(rate_steps(rx, on)) == [4, 7]
    on[4] = False
    assert list(rate_steps(rx, on)) == [7]


def _events(*args, **kw):
    """The events of `transition_events` as (class name, settled, time_s, distance_m, peak_error_pct)."""
    ev = transition_events(*args, **kw)
    return [(EVENTS[k], bool(ok), float(t), float(d), float(p))
            for k, ok, t, d, p in zip(ev.kind, ev.settled, ev.time_s, ev.distance_m, ev.peak_error_pct,
                                      strict=True)]


def test_transition_time_and_distance():
    t = np.arange(12) * 0.5
    d = t * 2.0  # 2 m/s
    rx = np.array([100.0] * 4 + [200.0] * 8)
    applied = np.array([100, 100, 100, 100, 120, 150, 175, 185, 195, 200, 200, 200], float)
    ev = _events(t, d, rx, applied, np.ones(12, bool))
    # the opening at tick 0 (in the band from the start), the step at tick 4 (first within 10 %,
    # >= 180, at tick 7, its peak error -40 % at tick 4), the closing at the end (in the band)
    assert ev[0] == ("rate_step", True, 1.5, 3.0, -40.0)
    assert ev[1] == ("pass_start", True, 0.0, 0.0, 0.0)
    assert ev[2] == ("pass_end", True, 0.0, 0.0, 0.0)
    # one rate step is too few for a mean: n/a, and the count says why
    m = transitions(t, d, rx, applied, np.ones(12, bool))
    assert (m.rate_step.events, m.rate_step.cut, m.transitions) == (1, 0, 1)
    assert np.isnan(m.transition_time_s_mean) and np.isnan(m.rate_step.peak_error_pct_mean)


def test_figures_rest_on_at_least_min_events():
    """Five steps of 1.5 s each: the mean and percentile are numbers; four: n/a."""
    t = np.arange(100) * 0.5
    rx = np.where((np.arange(100) // 10) % 2 == 0, 100.0, 200.0)
    applied = rx.copy()
    for k in range(10, 100, 10):   # each step settles 3 ticks (1.5 s) later
        applied[k:k + 3] = rx[k - 1]
    on = np.ones(100, bool)
    five = transitions(t[:60], 2 * t[:60], rx[:60], applied[:60], on[:60])
    assert five.rate_step.events == 5 and five.transition_time_s_mean == pytest.approx(1.5)
    assert five.rate_step.peak_error_pct_mean == pytest.approx(np.mean([50, 100, 50, 100, 50]))
    four = transitions(t[:50], 2 * t[:50], rx[:50], applied[:50], on[:50])
    assert four.rate_step.events == 4 and np.isnan(four.transition_time_s_mean)


def test_unsettled_step_is_cut():
    t = np.arange(8) * 1.0
    rx = np.array([100, 100, 200, 200, 100, 100, 100, 100], float)
    applied = np.array([100, 100, 110, 120, 110, 100, 100, 100], float)
    ev = _events(t, t, rx, applied, np.ones(8, bool))
    steps = [e for e in ev if e[0] == "rate_step"]
    # the step at 2 never settles before the step back at 4; the step back settles at once
    assert steps[0][:2] == ("rate_step", False) and np.isnan(steps[0][2]) and steps[0][4] == -45.0
    assert steps[1] == ("rate_step", True, 0.0, 0.0, 10.0)


def _track_of_steps():
    """One track at 0.5 s a tick, 2 m/s, of four rate steps (each 10 ticks apart) and their applied rates:

    - tick 5, 100 -> 200, a normal step: within 10 % (>= 180) from tick 8 on: 1.5 s; the sections
      closing at tick 13 (more than `SETTLE_HOLD_S` later) do not undo it;
    - tick 15, 200 -> 0, into zero: the sections close (applied NaN);
    - tick 25, 0 -> 300, cut: the implement turns off at tick 29 before the rate comes near 300;
    - tick 35, 100 -> 50 (after the turn), an overshoot: in the band at 37 (for less than the hold),
      out at 38-39 (40 < 45), back from 40 on: 2.5 s, not 1.
    """
    n = 50
    t = np.arange(n) * 0.5
    rx = np.full(n, 100.0)
    rx[5:15], rx[15:25], rx[25:30], rx[35:] = 200.0, 0.0, 300.0, 50.0
    applied = rx.copy()
    applied[5:8] = (120.0, 150.0, 170.0)
    applied[13:25] = np.nan
    applied[25:29] = (60.0, 150.0, 200.0, 240.0)
    applied[35:41] = (90.0, 60.0, 52.0, 40.0, 42.0, 46.0)
    on = np.ones(n, bool)
    on[29:31] = False  # a turn
    return t, 2.0 * t, rx, applied, on  # 2 m/s


def test_transitions_by_event_class():
    t, d, rx, applied, on = _track_of_steps()
    assert list(rate_steps(rx, on)) == [5, 15, 25, 35]
    ev = _events(t, d, rx, applied, on)
    by = {}
    for e in ev:
        by.setdefault(e[0], []).append(e[1:])
    # tick 5: settles in 1.5 s; tick 35 (after the turn): an overshoot back in the band from 40 on: 2.5 s
    assert by["rate_step"] == [(True, 1.5, 3.0, -40.0), (True, 2.5, 5.0, 80.0)]
    # tick 15, into zero: the sections closed at 13, before it, so nothing was going on before the
    # step: no transition
    assert "to_zero" not in by
    # the openings: tick 0 (in the band at once), tick 25 (the sections reopen under 300, cut by the turn
    # at 29: peak -80 %), tick 31 after the turn (in the band at once)
    assert [o[0] for o in by["pass_start"]] == [True, False, True]
    assert by["pass_start"][1][3] == -80.0
    # the closings: at 12 (every section closes, in the band), at 28 (the turn: out of the band since
    # the opening at 25, 1.5 s; peak -80 %), at the end (in the band)
    assert by["pass_end"] == [(True, 0.0, 0.0, 0.0), (True, 1.5, 3.0, -80.0), (True, 0.0, 0.0, 0.0)]


def test_a_step_to_zero_settles_where_the_product_stops():
    t = np.arange(20) * 0.5
    rx = np.where(np.arange(20) < 8, 100.0, 0.0)
    applied = rx.copy()
    applied[8:11] = (90.0, 40.0, 5.0)   # the product tails off: at most 10 % of 100 from tick 10
    applied[11:] = np.nan               # then the sections close
    ev = _events(t, 2 * t, rx, applied, np.ones(20, bool))
    zero = [e for e in ev if e[0] == "to_zero"]
    assert len(zero) == 1 and zero[0][:4] == ("to_zero", True, 1.0, 2.0) and np.isnan(zero[0][4])
    # the closing at 10 is under a zero rate: not a pass end
    assert [e[0] for e in ev] == ["to_zero", "pass_start"]


def test_events_of_a_stretch_are_those_before_upto():
    """A run accounted part by part: each stretch's events are its own ticks', its windows reach into
    the look-ahead; joined, they are the whole run's."""
    t, d, rx, applied, on = _track_of_steps()
    whole = transition_events(t, d, rx, applied, on)
    cut = 30   # in the turn (29-30 off)
    first = transition_events(t[:cut + 12], d[:cut + 12], rx[:cut + 12], applied[:cut + 12], on[:cut + 12],
                              upto=cut)
    second = transition_events(t[cut:], d[cut:], rx[cut:], applied[cut:], on[cut:])
    joined = TransitionEvents.joined([first, second])
    order = lambda ev: np.lexsort((ev.time_s, ev.kind))  # noqa: E731
    for name in ("kind", "settled"):
        assert np.array_equal(getattr(whole, name)[order(whole)], getattr(joined, name)[order(joined)])
    np.testing.assert_array_equal(whole.peak_error_pct[order(whole)], joined.peak_error_pct[order(joined)])


def test_a_step_within_the_band_at_once_takes_zero_and_none_gives_nan():
    t, d, rx, _, on = _track_of_steps()
    m = transitions(t, d, rx, rx.copy(), on)  # applied = prescribed: every step settles at once
    assert (m.transitions, m.to_zero.events, m.rate_step.cut) == (3, 1, 0)
    assert all(e[2] == 0.0 for e in _events(t, d, rx, rx.copy(), on))
    assert np.isnan(m.transition_time_s_mean)   # three steps: too few for a mean
    flat = transitions(t, d, np.full(t.size, 100.0), np.full(t.size, 100.0), on)
    assert (flat.transitions, flat.to_zero.events, flat.rate_step.cut) == (0, 0, 0)
    assert np.isnan(flat.transition_time_s_mean) and np.isnan(flat.rate_step.time_s_p95)


def test_skipped_area_counts_only_ground_that_asks_for_product():
    # Ten columns worked; columns 0-5 ask for 100 kg/ha, 6-9 for 0. Product on columns 0-4 and 9
    # (a zero-rate column that got product anyway); column 5 is a skip, 6-8 are off as prescribed.
    rx = np.zeros((4, 10))
    rx[:, :6] = 100.0
    rx[0, 7] = np.nan  # nodata asks for nothing either
    covered = np.zeros((4, 10))
    covered[:, :5] = covered[:, 9] = 1.0
    m = overlap_metrics(covered, np.zeros((4, 10)), np.zeros((4, 10)), np.ones((4, 10)),
                        np.ones((4, 10), bool), rx)
    assert m.skip_area_pct == pytest.approx(100 * 1 / 6)  # 1 of the 6 columns that ask
    assert m.off_as_prescribed_area_pct == pytest.approx(100 * 3 / 10)  # 3 of the 10 worked
    # Together they are the old figure, bare over worked: (1 + 3) / 10.
    assert m.skip_area_pct * 6 / 10 + m.off_as_prescribed_area_pct == pytest.approx(100 * 4 / 10)


def test_the_metrics_table_is_the_one_source_of_summary_report_and_tolerances():
    from vrsim.services.outputs.summary import summary_rows
    from vrsim.services.sim.accuracy import TOLERANCES

    keys = [m.key for m in METRICS]
    assert len(keys) == len(set(keys))
    assert TOLERANCES == {m.key: m.tolerance for m in METRICS if m.tolerance is not None}
    assert "wall_time_s" not in TOLERANCES and "mae_kg_ha" in TOLERANCES  # the machine is not held
    assert summary_rows() == tuple((m.label, m.key, m.unit) for m in METRICS if m.label)
    # Every row says how its figure comes from a run's accounts; every figure the metric functions
    # compute is a row of the table, read from its part.
    assert all(m.of is not None for m in METRICS)
    sources = {m.of for m in METRICS}
    for part, cls in (("map", MapMetrics), ("overlap", OverlapMetrics), ("limits", LimitMetrics)):
        assert {f"{part}.{f.name}" for f in dataclasses.fields(cls)} <= sources, part
    # Each event class's figures (the rate steps' count is `transitions`, settled; a step to zero has
    # no peak error).
    read = {f"transitions.{kind}.{f.name}" for kind in EVENTS for f in dataclasses.fields(EventFigures)}
    assert read - sources == {"transitions.rate_step.events", "transitions.to_zero.peak_error_pct_mean"}


def _accounts(ticks=4, wall_time_s=2.0):
    """Accounts as `services.sim.accounting.account` gives them, their parts filled with counts."""
    def part(cls, first):
        return cls(*(float(first + i) for i, _ in enumerate(dataclasses.fields(cls))))

    implement = Implement(width_m=6.0, sections=2)   # a gated meter: no spread pattern, cv_pct n/a
    scenario = SimpleNamespace(name="s", seed=3, implement=implement,
                               timing=SimpleNamespace(control_period_s=0.05))
    grid = SimpleNamespace(map_unit="lb/ac", in_map_unit=lambda kg_ha: kg_ha / 2.0)
    world = SimpleNamespace(scenario=scenario, field=SimpleNamespace(area_ha=1.5), grid=grid)
    setting = SimpleNamespace(world=world, ticks=ticks, path_length_m=1.5 * (ticks - 1) if ticks else 0.0,
                              check=SimpleNamespace(max_speed_m_s=4.0))
    return SimpleNamespace(setting=setting, map=part(MapMetrics, 100),
                           transitions=TransitionMetrics(*(part(EventFigures, 200 + 10 * k)
                                                           for k in range(len(EVENTS)))),
                           overlap=part(OverlapMetrics, 300),
                           limits=part(LimitMetrics, 400),
                           timing=SimpleNamespace(stage_s={"control_s": 1.0}, wall_time_s=wall_time_s))


def test_the_summary_reads_each_figure_off_the_accounts_in_table_order():
    a = _accounts()
    s = summary(a)
    assert list(s) == ["scenario", *[m.key for m in METRICS], "rate_unit", "in_rate_unit", "seed", "stage_s"]
    # The figures in kg/ha again in the map's unit, from the rows whose unit is kg/ha.
    assert s["rate_unit"] == "lb/ac"
    assert s["in_rate_unit"] == {k: s[f"{k}_kg_ha"] / 2.0 for k in ("mae", "rmse", "bias")}
    assert (s["scenario"], s["seed"], s["stage_s"]) == ("s", 3, {"control_s": 1.0})
    assert s["mae_kg_ha"] == a.map.mae_kg_ha and s["overlap_kg"] == a.overlap.overlap_kg
    assert s["transitions"] == a.transitions.transitions
    assert s["limited_area_pct"] == a.limits.limited_area_pct
    assert (s["ticks"], s["sim_time_s"], s["wall_time_s"], s["realtime_factor"]) == (4, 0.2, 2.0, 0.1)
    assert (s["path_length_m"], s["section_widths_m"], s["sections"]) == (4.5, [3.0, 3.0], 2)
    assert (s["field_area_ha"], s["max_speed_m_s"]) == (1.5, 4.0)
    assert math.isnan(s["cv_pct"]) and math.isnan(s["effective_width_m"])
    assert summary(_accounts(ticks=0))["path_length_m"] == 0.0


def test_within_band_counts_bare_and_partly_covered_ground():
    """Ground that asks for product and was worked but got none (sections closed early) is outside the
    band; a cell the working width swept only in part is judged on the part swept."""
    rx, field, cover = _grid()
    worked = np.ones(rx.shape)
    applied = rx.copy()
    applied[0, :] = 0.0                  # a row worked but left bare: 10 % of the worked ground
    worked[9, :], applied[9, :] = 0.5, 50.0   # the last row swept half, applied in full on that half
    rx[5, 5], applied[5, 5] = 0.0, 0.0   # asks for nothing: not judged
    m = map_metrics(rx, applied, np.where(applied > 0, 1.0, 0.0), field, 0.01,
                    applied_total_kg=applied.sum() * 0.01, worked_fraction=worked)
    judged = 100 - 1 - 10 * 0.5          # cells weighted by their worked share
    assert m.within_10pct_area_pct == pytest.approx(100 * (judged - 10) / judged)
    band = within_band(rx, applied, worked, field)
    assert band.within_5pct_pct == pytest.approx(m.within_5pct_area_pct)
    # the same ground covered only where product landed would have flattered it: 100 %
    assert map_metrics(rx, applied, np.where(applied > 0, 1.0, 0.0), field, 0.01,
                       applied_total_kg=applied.sum() * 0.01,
                       worked_fraction=np.where(applied > 0, worked, 0.0)).within_10pct_area_pct == 100.0
