import dataclasses

import numpy as np
import pytest

from services.sim.metrics import (
    METRICS,
    MapMetrics,
    TransitionMetrics,
    map_metrics,
    rate_steps,
    summary,
    transitions,
)


def _grid(rows=10, cols=10, rate=100.0):
    rx = np.full((rows, cols), rate)
    field = np.ones((rows, cols), bool)
    cover = np.ones((rows, cols))
    return rx, field, cover


def test_constant_error_gives_known_mae_rmse_bias():
    rx, field, cover = _grid()
    applied = rx + 4.0  # +4 % everywhere
    cell_ha = 0.01
    m = map_metrics(rx, applied, cover, field, cell_ha, applied_total_kg=applied.sum() * cell_ha)
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
    m = map_metrics(rx, applied, cover, field, 0.01, applied_total_kg=applied.sum() * 0.01)
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
                    off_grid_kg=1.5)
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


def test_unsettled_step_is_not_counted():
    t = np.arange(8) * 1.0
    rx = np.array([100, 100, 200, 200, 100, 100, 100, 100], float)
    applied = np.array([100, 100, 110, 120, 110, 100, 100, 100], float)
    m = transitions(t, t, rx, applied, np.ones(8, bool))
    assert m.transitions == 1  # the step at 2 never settles before the step back at 4
    assert m.transition_time_s_mean == 0.0


def test_the_metrics_table_is_the_one_source_of_summary_report_and_tolerances():
    from services.outputs.summary import SUMMARY_ROWS
    from services.sim.accuracy import TOLERANCES

    keys = [m.key for m in METRICS]
    assert len(keys) == len(set(keys))
    assert TOLERANCES == {m.key: m.tolerance for m in METRICS if m.tolerance is not None}
    assert "wall_time_s" not in TOLERANCES and "mae_kg_ha" in TOLERANCES  # the machine is not held
    assert SUMMARY_ROWS == tuple((m.label, m.key, m.unit) for m in METRICS if m.label)
    # Every figure the metric functions compute is a row of the table.
    computed = {f.name for f in dataclasses.fields(MapMetrics)} | {f.name for f in dataclasses.fields(
        TransitionMetrics)}
    assert computed <= set(keys)
    figures = {k: float(i) for i, k in enumerate(keys)}
    assert list(summary("s", 3, figures)) == ["scenario", *keys, "seed"]
    with pytest.raises(KeyError, match="coverage_pct"):
        summary("s", 3, {k: v for k, v in figures.items() if k != "coverage_pct"})
