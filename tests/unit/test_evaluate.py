"""Per-point accuracy of as-applied logs (services.sim.evaluate, metrics.point_metrics) and the run's log
(services.sim.aslog), on logs whose figures are known by construction."""

import math

import numpy as np
import pytest
from affine import Affine

from vrsim.common import MapError
from vrsim.maps import Grid, PointLog
from vrsim.services.sim.aslog import _compass_deg
from vrsim.services.sim.evaluate import error_grid, evaluate
from vrsim.services.sim.metrics import POINT_METRICS, point_metrics
from vrsim.vehicle import Field

FIELD = Field.rectangle(200.0, 100.0, lat=52.0, lon=10.0)


def _east_log(rates_applied, rates_target, speed=1.0, **kw) -> PointLog:
    """One point a second driving east at `speed` m/s along y = 50.5 m into FIELD, from x = 10.5 m (cell
    centres of a 1 m grid on FIELD's corner)."""
    n = len(rates_applied)
    minx, miny, _, _ = FIELD.polygon.bounds
    t = np.arange(n, dtype=float)
    return PointLog(minx + 10.5 + speed * t, np.full(n, miny + 50.5), FIELD.crs, applied=rates_applied,
                    target=rates_target, unit=kw.pop("unit", "kg/ha"), time_s=t,
                    start=np.datetime64("2026-05-01T10:00:00"), source="east", **kw)


def _step_map(step_x_m: float, low=100.0, high=200.0) -> Grid:
    """1 m cells over FIELD: `low` west of x = minx + step_x_m, `high` east of it."""
    minx, miny, maxx, maxy = FIELD.polygon.bounds
    cols, rows = int(maxx - minx), int(maxy - miny)
    rates = np.where(np.arange(cols)[None, :] < step_x_m, low, high) * np.ones((rows, 1))
    return Grid(rates, Affine(1.0, 0.0, minx, 0.0, -1.0, maxy), FIELD.crs, source="step")


def test_point_metrics_by_hand():
    applied = np.array([110.0, 90.0, 104.0, np.nan, 100.0])
    target = np.array([100.0, 100.0, 100.0, 100.0, 0.0])
    compared = np.array([True, True, True, True, False])
    m = point_metrics(applied, target, np.arange(5.0), np.arange(5.0), compared)
    assert m.points == 3  # the NaN is not compared
    assert m.mae == pytest.approx(8.0)
    assert m.bias == pytest.approx(4.0 / 3)
    assert m.rmse == pytest.approx(math.sqrt((100 + 100 + 16) / 3))
    assert m.mass_balance_pct == pytest.approx(100 * 4.0 / 300)
    assert m.within_5pct_pct == pytest.approx(100 / 3)
    assert m.within_10pct_pct == pytest.approx(100.0)
    assert [f.name for f in __import__("dataclasses").fields(m)] == [p.key for p in POINT_METRICS]


def test_point_transitions_are_the_runs_own():
    """Six steps of the target, each reached by the applied rate 2 points (2 s, 2 m) later: the run's own
    classes; the step threshold scales with the unit (5 kg/ha), so the same log in t/ha finds the same
    steps; a gap in the records compared (sections closed) is a pass end and a pass start, and leaves
    fewer than 5 steps on either side: n/a."""
    target = np.tile(np.repeat([100.0, 200.0], 5), 4)[:35]
    applied = target.copy()
    for k in range(5, 35, 5):
        applied[k:k + 2] = (target[k - 1] + target[k]) / 2   # half way for two points
    t = np.arange(35.0)
    m = point_metrics(applied, target, t, t, np.ones(35, bool))
    assert (m.transitions, m.transition_time_s_mean, m.transition_distance_m_mean) == (6, 2.0, 2.0)
    assert m.transition_peak_error_pct_mean == pytest.approx(np.mean([50, 25, 50, 25, 50, 25]))
    assert (m.pass_start_events, m.pass_end_events, m.to_zero_events) == (1, 1, 0)
    scaled = point_metrics(applied / 1000, target / 1000, t, t, np.ones(35, bool), step_scale=1000.0)
    assert (scaled.transitions, scaled.transition_time_s_mean) == (6, 2.0)
    compared = np.ones(35, bool)
    compared[4], compared[20] = False, False                   # closed across two steps
    gap = point_metrics(applied, target, t, t, compared)
    assert (gap.pass_start_events, gap.pass_end_events, gap.transitions) == (3, 3, 4)
    assert math.isnan(gap.transition_time_s_mean)


def test_logged_target_and_summary_keys():
    ev = evaluate(_east_log([100.0, 105.0, 95.0, 100.0], [100.0] * 4))
    s = ev.summary()
    assert list(s) == ["points", "unit", *[m.key for m in POINT_METRICS if m.key != "points"], "excluded"]
    assert s["points"] == 4 and s["unit"] == "kg/ha" and s["mae"] == pytest.approx(2.5)
    assert ev.against == "logged target"


def test_prescription_with_delay_compares_where_the_product_lands():
    """The machine applies the new rate 3 s before it reaches the step (its controller looked ahead by
    the 3 s delivery delay): compared with the map at the point 3 s later, every point matches; at
    the logged point the three points before the step are off."""
    n = 40
    x = 10.5 + np.arange(n, dtype=float)  # metres east of minx, at 1 m/s
    step_x = 30.0  # the map's step, metres east of minx: log point 20 is past it
    applied = np.where(x + 3.0 >= step_x, 200.0, 100.0)
    rx = _step_map(step_x)
    log = _east_log(applied, np.full(n, np.nan))
    exact = evaluate(log, rx, delay_s=3.0)
    assert exact.metrics.mae == pytest.approx(0.0)
    assert exact.metrics.points == n - 3  # the last 3 s have no landing point on the log
    late = evaluate(log, rx)
    assert late.metrics.mae == pytest.approx(3 * 100.0 / n)
    assert late.against == "step"


def test_field_section_states_and_units():
    n = 10
    sections = np.zeros((n, 2), bool)
    sections[5:, 0] = True
    log = _east_log(np.full(n, 90.0), np.full(n, 100.0), sections_on=sections)
    ev = evaluate(log)
    assert ev.metrics.points == 5  # work on but no section on: not applying
    assert ev.excluded == {"implement_off": 0, "no_section_on": 5, "target_0": 0, "no_applied_rate": 0,
                           "no_target": 0, "outside_field": 0}
    outside = Field.rectangle(50.0, 50.0, lat=52.1, lon=10.1)
    with pytest.raises(MapError, match="no point to compare.*inside the field"):
        evaluate(log, field=outside)
    lb = _east_log(np.full(n, 100.0), np.full(n, 100.0), unit="lb/ac")
    assert evaluate(lb, _step_map(500.0)).metrics.applied_mean == pytest.approx(112.085, rel=1e-5)
    gal = _east_log(np.full(n, 10.0), np.full(n, 10.0), unit="gal/ac")
    with pytest.raises(MapError, match="east: cannot compare.*gal/ac.*density"):
        evaluate(gal, _step_map(500.0))
    with pytest.raises(MapError, match="unit of its rates is 'not stated'.*--unit"):
        evaluate(_east_log([1.0, 2.0], [1.0, 2.0], unit=""))
    with pytest.raises(MapError, match="--delay-s -1"):
        evaluate(log, delay_s=-1)


def test_error_grid_on_the_prescription_and_without():
    n = 20
    log = _east_log(np.full(n, 110.0), np.full(n, 100.0))
    rx = _step_map(500.0, low=100.0)
    g = error_grid(evaluate(log, rx), rx)
    assert g.quantity == "difference" and g.unit == "kg/ha"
    assert np.count_nonzero(np.isfinite(g.rates_kg_ha)) == n  # one 1 m cell per point
    assert np.nanmax(g.rates_kg_ha) == pytest.approx(10.0)
    g = error_grid(evaluate(log))
    assert g.cell_size == (5.0, 5.0) and g.rates_kg_ha.shape == (1, 5)  # 19 m of points, half a cell round
    assert np.all(g.rates_kg_ha == pytest.approx(10.0))


def test_compass_heading():
    assert _compass_deg(np.array([0.0, np.pi / 2, np.pi, -np.pi / 2])).tolist() == [90.0, 0.0, 270.0, 180.0]


def test_target_0_width_0_and_implement_off_are_left_out_by_reason():
    target = np.array([100.0, 0.0, 100.0, 100.0, 100.0, 0.0])
    applied = np.array([100.0, 50.0, 80.0, 90.0, np.nan, 0.0])
    width = np.array([12.0, 12.0, 0.0, 12.0, 12.0, 12.0])
    work = np.array([True, True, True, False, True, True])
    log = _east_log(applied, target, width_m=width, work_on=work)
    ev = evaluate(log)
    assert ev.metrics.points == 1 and ev.compared.tolist() == [True] + [False] * 5
    assert ev.excluded == {"implement_off": 1, "no_section_on": 1, "target_0": 2, "no_applied_rate": 1,
                           "no_target": 0, "outside_field": 0}
    ev = evaluate(log, include_zero_target=True)
    assert ev.metrics.points == 3 and ev.metrics.mae == pytest.approx(50.0 / 3)
    assert ev.excluded["target_0"] == 0


def write_iso_time_export(folder, n: int, seed: int = 3):
    """A zipped point shapefile of `n` records with ISO 8601 text times (the slow path of the point-log
    reader) in `folder`: (its path, the target rate of each record, kg/ha). `bench/bench_maps.py` times
    reading and evaluating 40,000 of them."""
    import zipfile

    import pyogrio
    import shapely

    rng = np.random.default_rng(seed)
    t = np.arange(n)
    target = np.where(rng.random(n) < 0.05, 0.0, rng.choice([100.0, 150.0, 200.0], n))
    stamps = np.datetime64("2026-05-01T10:00:00", "ms") + t.astype("timedelta64[s]")
    export = folder / "export"
    export.mkdir()
    pyogrio.raw.write(str(export / "big.shp"), shapely.to_wkb(shapely.points(10 + (t % 400) * 2e-5,
                                                                            52 + (t // 400) * 1e-4)),
                      [np.datetime_as_string(stamps).astype(object), target + rng.normal(0, 3, n), target,
                       np.full(n, 12.0), np.full(n, "kg/ha", dtype=object)],
                      ["IsoTime", "AppliedRat", "TargetRate", "SWATHWIDTH", "rate_unit"],
                      driver="ESRI Shapefile", geometry_type="Point", crs="EPSG:4326")
    with zipfile.ZipFile(folder / "big.zip", "w") as z:
        for name in sorted(p.name for p in export.iterdir()):
            z.write(export / name, name)
    return folder / "big.zip", target


def test_a_point_export_with_iso_text_times_is_read_and_evaluated_whole(tmp_path):
    """A zipped point shapefile with ISO 8601 text times (the slow path of the reader): every record
    read, the zero-target ones left out and counted. (How long 40,000 take: `bench/bench_maps.py`,
    ``point_export_40k_evaluate_s``.)"""
    from vrsim.maps import read_point_log

    path, target = write_iso_time_export(tmp_path, 4_000)
    log = read_point_log(path)
    ev = evaluate(log)
    assert len(log.time_s) == 4_000
    assert ev.metrics.points == (target > 0).sum() and ev.excluded["target_0"] == (target == 0).sum()
