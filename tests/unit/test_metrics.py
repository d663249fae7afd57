import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from services.sim.metrics import (
    METRICS,
    LimitMetrics,
    MapMetrics,
    OverlapMetrics,
    map_metrics,
    overlap_metrics,
    summary,
    within_band,
)
from services.sim.transitions import TransitionMetrics, rate_steps, transitions
from vehicle import Implement


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


def test_transition_time_and_distance():
    t = np.arange(12) * 0.5
    d = t * 2.0  # 2 m/s
    rx = np.array([100.0] * 4 + [200.0] * 8)
    applied = np.array([100, 100, 100, 100, 120, 150, 175, 185, 195, 200, 200, 200], float)
    m = transitions(t, d, rx, applied, np.ones(12, bool))
    # step at tick 4; first within 10 % (>= 180) at tick 7
    assert m.transitions == 1
    assert m.transition_time_s_mean == pytest.approx(1.5)
    assert m.transition_distance_m_mean == pytest.approx(3.0)


def test_unsettled_step_is_cut():
    t = np.arange(8) * 1.0
    rx = np.array([100, 100, 200, 200, 100, 100, 100, 100], float)
    applied = np.array([100, 100, 110, 120, 110, 100, 100, 100], float)
    m = transitions(t, t, rx, applied, np.ones(8, bool))
    assert m.transitions == 1  # the step at 2 never settles before the step back at 4
    assert m.transitions_cut == 1
    assert m.transition_time_s_mean == 0.0


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


def test_transitions_settle_and_leave_out_steps_into_zero_and_cut_steps():
    t, d, rx, applied, on = _track_of_steps()
    assert list(rate_steps(rx, on)) == [5, 15, 25, 35]
    m = transitions(t, d, rx, applied, on)
    assert (m.transitions, m.transitions_to_zero, m.transitions_cut) == (2, 1, 1)
    assert m.transition_time_s_mean == pytest.approx((1.5 + 2.5) / 2)
    assert m.transition_distance_m_mean == pytest.approx(2 * (1.5 + 2.5) / 2)
    # The mean and the 95th percentile describe the same two steps: mean <= p95 <= max here.
    assert m.transition_time_s_p95 == pytest.approx(np.percentile([1.5, 2.5], 95))
    assert 1.5 <= m.transition_time_s_mean <= m.transition_time_s_p95 <= 2.5
    assert m.transition_distance_m_p95 == pytest.approx(2 * m.transition_time_s_p95)


def test_a_step_within_the_band_at_once_takes_zero_and_none_gives_nan():
    t, d, rx, _, on = _track_of_steps()
    m = transitions(t, d, rx, rx.copy(), on)  # applied = prescribed: every non-zero step settles at once
    assert (m.transitions, m.transitions_to_zero, m.transitions_cut) == (3, 1, 0)
    assert m.transition_time_s_mean == m.transition_time_s_p95 == 0.0
    flat = transitions(t, d, np.full(t.size, 100.0), np.full(t.size, 100.0), on)
    assert (flat.transitions, flat.transitions_to_zero, flat.transitions_cut) == (0, 0, 0)
    assert np.isnan(flat.transition_time_s_mean) and np.isnan(flat.transition_time_s_p95)


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
    from services.outputs.summary import summary_rows
    from services.sim.accuracy import TOLERANCES

    keys = [m.key for m in METRICS]
    assert len(keys) == len(set(keys))
    assert TOLERANCES == {m.key: m.tolerance for m in METRICS if m.tolerance is not None}
    assert "wall_time_s" not in TOLERANCES and "mae_kg_ha" in TOLERANCES  # the machine is not held
    assert summary_rows() == tuple((m.label, m.key, m.unit) for m in METRICS if m.label)
    # Every row says how its figure comes from a run's accounts; every figure the metric functions
    # compute is a row of the table, read from its part.
    assert all(m.of is not None for m in METRICS)
    sources = {m.of for m in METRICS}
    for part, cls in (("map", MapMetrics), ("transitions", TransitionMetrics), ("overlap", OverlapMetrics),
                      ("limits", LimitMetrics)):
        assert {f"{part}.{f.name}" for f in dataclasses.fields(cls)} <= sources, part


def _accounts(ticks=4, wall_time_s=2.0):
    """Accounts as `services.sim.accounting.account` gives them, their parts filled with counts."""
    def part(cls, first):
        return cls(*(float(first + i) for i, _ in enumerate(dataclasses.fields(cls))))

    implement = Implement(width_m=6.0, sections=2)   # a gated meter: its rectangles' cv_pct is 0
    scenario = SimpleNamespace(name="s", seed=3, implement=implement,
                               timing=SimpleNamespace(control_period_s=0.05))
    grid = SimpleNamespace(map_unit="lb/ac", in_map_unit=lambda kg_ha: kg_ha / 2.0)
    world = SimpleNamespace(scenario=scenario, field=SimpleNamespace(area_ha=1.5), grid=grid)
    setting = SimpleNamespace(world=world, ticks=ticks, path_length_m=1.5 * (ticks - 1) if ticks else 0.0,
                              check=SimpleNamespace(max_speed_m_s=4.0))
    return SimpleNamespace(setting=setting, map=part(MapMetrics, 100),
                           transitions=part(TransitionMetrics, 200), overlap=part(OverlapMetrics, 300),
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
    assert (s["field_area_ha"], s["max_speed_m_s"], s["cv_pct"]) == (1.5, 4.0, 0.0)
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
