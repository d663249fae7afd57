"""`vrsim evaluate` weighted as the ground is (issue #37): mass balance and within-shares by each
record's area, standstill records and outliers left out and counted, figures per timestamp beside
those per record, sessions split at gaps with a picture panel each; on logs whose figures are known
by construction."""

import dataclasses

import numpy as np
import pytest

from vrsim.common import MapError
from vrsim.maps import PointLog, read_point_log, write_points
from vrsim.services.outputs.evaluation import (
    MAX_PANELS,
    _plot_log_timeseries,
    _session_panels,
    text_evaluation,
    write_evaluation,
)
from vrsim.services.sim.evaluate import error_grid, evaluate

CRS = "EPSG:32632"  # metres: a record's distance is its step along x
N = 120
STOP = slice(50, 60)  # ten records of a stop: 5 cm a second, 3,000 kg/ha


def _drive(stop_applied=3000.0, logged_speed=False) -> PointLog:
    """`N` records a second driving east at 2 m/s with a 12 m width, target 100 kg/ha, applied 98 and
    103 by turns; the records of `STOP` creep 5 cm a second applying `stop_applied`."""
    step_m = np.full(N, 2.0)
    step_m[STOP] = 0.05
    applied = np.where(np.arange(N) % 2 == 0, 98.0, 103.0)
    applied[STOP] = stop_applied
    t = np.arange(N, dtype=float)
    return PointLog(500_000.0 + np.cumsum(step_m), np.full(N, 5_800_000.0), CRS, applied=applied,
                    target=np.full(N, 100.0), unit="kg/ha", time_s=t,
                    start=np.datetime64("2026-05-01T10:00:00"), width_m=np.full(N, 12.0),
                    distance_m=step_m, speed_m_s=step_m if logged_speed else None, source="drive")


def _area_mass_balance_pct(log: PointLog, keep) -> float:
    """sum(applied x area) / sum(target x area) - 1 over the records `keep`, in %."""
    area = log.distance_m * log.width_m
    return 100.0 * ((log.applied * area)[keep].sum() / (log.target * area)[keep].sum() - 1.0)


def test_standstill_records_are_left_out_counted_and_move_nothing():
    log = _drive()
    ev = evaluate(log)
    moving = np.ones(N, bool)
    moving[STOP] = False
    m = ev.metrics
    assert (m.standstill_records, m.points, m.weighting, m.speed_from) == (10, N - 10, "area",
                                                                           "distance over time")
    assert np.flatnonzero(ev.standstill).tolist() == list(range(50, 60))
    assert m.mass_balance_pct == pytest.approx(_area_mass_balance_pct(log, moving), abs=1e-12)
    unmoved = evaluate(dataclasses.replace(log, applied=np.where(moving, log.applied, 100.0))).metrics
    assert unmoved.mass_balance_pct == pytest.approx(m.mass_balance_pct, abs=1e-12)
    assert unmoved.within_10pct_pct == m.within_10pct_pct == 100.0
    # Without the cut-off, the same records are outliers (3,000 > 5 x 100): left out unless included.
    loose = evaluate(log, standstill_m_s=0.0).metrics
    assert (loose.standstill_records, loose.outlier_records, loose.points) == (0, 10, N - 10)
    assert loose.mass_balance_pct == pytest.approx(m.mass_balance_pct, abs=1e-12)
    kept = evaluate(log, standstill_m_s=0.0, include_outliers=True).metrics
    assert kept.points == N and kept.outliers_included
    assert kept.mass_balance_pct == pytest.approx(_area_mass_balance_pct(log, np.ones(N, bool)))
    assert kept.mass_balance_pct > m.mass_balance_pct + 1.0


def test_a_written_log_with_standstill_outliers_read_back(tmp_path):
    """The same drive written by `write_points` (its speed logged; no distance, so each record alike)
    and read back: the stop's records left out and counted by their logged speed, the mass balance
    that of the moving records, whatever the stop applied."""
    got = []
    for stop_applied in (3000.0, 100.0):
        path = write_points(_drive(stop_applied, logged_speed=True), tmp_path / f"drive{stop_applied:g}.gpkg")
        got.append(evaluate(read_point_log(path)).metrics)
    huge, plain = got
    applied = np.where(np.arange(N) % 2 == 0, 98.0, 103.0)
    moving = np.ones(N, bool)
    moving[STOP] = False
    assert (huge.weighting, huge.speed_from, huge.standstill_records, huge.points) == (
        "record", "logged speed", 10, N - 10)
    assert huge.mass_balance_pct == pytest.approx(100.0 * (applied[moving].sum() / (100.0 * (N - 10)) - 1))
    assert huge.mass_balance_pct == pytest.approx(plain.mass_balance_pct, abs=1e-12)
    assert huge.outlier_records == 0  # at a standstill first: each record is counted once


def test_outliers_counted_and_left_out_unless_included():
    n = 40
    applied = np.full(n, 100.0)
    applied[[5, 17, 30]] = [600.0, 800.0, 501.0]  # above 5 x 100
    applied[8] = 499.0  # below it: a bad record, not an outlier
    log = PointLog(500_000.0 + 2.0 * np.arange(n), np.full(n, 5_800_000.0), CRS, applied=applied,
                   target=np.full(n, 100.0), time_s=np.arange(n, dtype=float), width_m=np.full(n, 12.0),
                   distance_m=np.full(n, 2.0), source="outliers")
    ev = evaluate(log)
    assert (ev.metrics.outlier_records, ev.metrics.points, ev.metrics.outliers_included) == (3, 37, False)
    assert np.flatnonzero(ev.outlier).tolist() == [5, 17, 30] and not ev.compared[[5, 17, 30]].any()
    assert ev.metrics.mass_balance_pct == pytest.approx(100.0 * 399.0 / (37 * 100.0))
    kept = evaluate(log, include_outliers=True).metrics
    assert (kept.points, kept.outlier_records) == (40, 3)
    assert kept.mass_balance_pct == pytest.approx(100.0 * (399.0 + 500 + 700 + 401) / 4000.0)
    assert evaluate(log, outlier_multiple=4.9).metrics.outlier_records == 4
    # A record applying where its target is 0 is left out as target_0 (counted in `excluded`);
    # --include-zero-target compares exactly those, so they are not outliers then.
    zero = PointLog(log.x[:4], log.y[:4], CRS, applied=[100.0, 50.0, 100.0, 100.0],
                    target=[100.0, 0.0, 100.0, 100.0], time_s=np.arange(4.0), source="zero")
    assert evaluate(zero).excluded["target_0"] == 1
    with_zero = evaluate(zero, include_zero_target=True).metrics
    assert (with_zero.points, with_zero.outlier_records) == (4, 0)


def test_per_timestamp_beside_per_record_for_one_record_per_section():
    """Two 6 m sections a record each, ten timestamps: at the first, one section applies 20 % over and
    the other 20 % under. Per record 18 of 20 are within 10 %; per timestamp, the machine's rate (their
    mean) is on target at every one."""
    n_t = 10
    t = np.repeat(np.arange(n_t, dtype=float), 2)
    x = 500_000.0 + 2.0 * t + np.tile([0.0, 0.001], n_t)
    y = 5_800_000.0 + np.tile([3.0, -3.0], n_t)
    applied = np.full(2 * n_t, 100.0)
    applied[:2] = [120.0, 80.0]
    log = PointLog(x, y, CRS, applied=applied, target=np.full(2 * n_t, 100.0), time_s=t,
                   width_m=np.full(2 * n_t, 6.0), distance_m=np.full(2 * n_t, 2.0),
                   section_id=np.tile([1, 2], n_t), source="sections")
    m = evaluate(log).metrics
    assert (m.points, m.timestamps, m.weighting) == (20, 10, "area")
    assert m.within_10pct_pct == pytest.approx(90.0)
    assert m.within_10pct_timestamps_pct == pytest.approx(100.0)
    assert m.mass_balance_pct == pytest.approx(0.0, abs=1e-12)


def test_area_only_where_every_record_compared_has_one():
    """One record without a distance: the records are weighed alike (their logged speed still finds
    the stop)."""
    log = _drive(logged_speed=True)
    distance = log.distance_m.copy()
    distance[3] = np.nan
    m = evaluate(dataclasses.replace(log, distance_m=distance)).metrics
    assert (m.weighting, m.standstill_records) == ("record", 10)
    moving = np.ones(N, bool)
    moving[STOP] = False
    assert m.mass_balance_pct == pytest.approx(100.0 * (log.applied[moving].sum() / (100.0 * (N - 10)) - 1))


def _days(sessions: int, per_session: int = 30) -> PointLog:
    """`sessions` runs of `per_session` records a second, each two days after the one before."""
    n = sessions * per_session
    t = np.arange(n, dtype=float) % per_session + np.repeat(np.arange(sessions) * 2 * 86_400.0, per_session)
    return PointLog(500_000.0 + 2.0 * np.arange(n), np.full(n, 5_800_000.0), CRS,
                    applied=np.full(n, 101.0), target=np.full(n, 100.0), time_s=t,
                    start=np.datetime64("2026-05-01T10:00:00"), width_m=np.full(n, 12.0),
                    distance_m=np.full(n, 2.0), source="days")


def test_a_log_with_a_gap_of_days_is_two_sessions_and_two_panels(tmp_path):
    ev = evaluate(_days(2))
    assert ev.metrics.sessions == 2 and ev.session.tolist() == [0] * 30 + [1] * 30
    assert ev.metrics.standstill_records == 0  # a session's first record moves over the logger's period
    assert _session_panels(ev) == [0, 1]
    assert _plot_log_timeseries(ev, str(tmp_path / "two.png")) == 2
    written = write_evaluation(ev, error_grid(ev), str(tmp_path / "out"))
    assert (tmp_path / "out" / "timeseries.png").stat().st_size > 0 and "report.html" in written
    assert "Sessions" in text_evaluation(ev)


def test_at_most_twelve_panels_the_busiest_and_says_how_many(tmp_path):
    log = _days(15)
    applied = log.applied.copy()
    applied[:30 * 3] = np.nan  # the first three sessions have no record compared
    ev = evaluate(dataclasses.replace(log, applied=applied))
    assert ev.metrics.sessions == 15 and MAX_PANELS == 12
    assert _session_panels(ev) == list(range(3, 15))
    assert _plot_log_timeseries(ev, str(tmp_path / "many.png")) == 12


def test_text_says_the_weighting_and_the_cut_offs():
    text = text_evaluation(evaluate(_drive()))
    for needle in ("% of area", "Weighted by", "area (each record's distance x width)",
                   "Standstill records left out", "ground speed below 0.5 m/s, from distance over time",
                   "Outlier records", "applied above 5x the target; left out", "Timestamps within +-10 %"):
        assert needle in text, (needle, text)


def test_cut_offs_out_of_range_are_refused():
    with pytest.raises(MapError, match="--standstill-m-s -1"):
        evaluate(_drive(), standstill_m_s=-1)
    with pytest.raises(MapError, match="--outlier-multiple 1.0: must be a number above 1"):
        evaluate(_drive(), outlier_multiple=1.0)
    everything_slow = dataclasses.replace(_drive(), distance_m=np.full(N, 0.01))
    with pytest.raises(MapError, match="no point to compare.*120 at a standstill"):
        evaluate(everything_slow)
