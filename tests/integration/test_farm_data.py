"""A run's farm-data outputs (taskdata/ TimeLog, as-applied points, prescription/as-applied/error
GeoTIFFs, track.csv, summary.json, report.html) read back by independent code paths; the round trip
run -> TimeLog -> `vrsim evaluate`; `vrsim evaluate` on a real John Deere export."""

import csv
import json
import os
import subprocess
import time

import numpy as np
import pytest
import rasterio

from tests.conftest import VRSIM
from vrsim import maps
from vrsim.services.outputs.write import write_outputs
from vrsim.services.sim import run, scenario
from vrsim.services.sim.metrics import METRICS, point_metrics

SCENARIO = """
name = "farm"
seed = 4
[field]
rectangle = { width_m = 72.0, length_m = 150.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "zones"
cell_size_m = 2.2
params = { n_zones = 5 }
[implement]
width_m = 12.0
sections = 4
shaft_rpm_max = 120.0
[output]
%s
"""
DEERE = os.path.join("data", "asapplied", "jd-gen4-application-point-onehertz.zip")


def vrsim(*args):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=300)


def scenario_file(folder, output="") -> str:
    path = os.path.join(folder, "farm.toml")
    with open(path, "w") as fh:
        fh.write(SCENARIO % output)
    return path


@pytest.fixture(scope="module")
def farm_run(tmp_path_factory):
    """One run in process, its outputs written as `vrsim run` writes them: (result, out folder)."""
    folder = tmp_path_factory.mktemp("farm")
    # The track as text too (every scenario but the default writes track.parquet alone).
    farm = scenario.load(scenario_file(str(folder)))
    result = run(scenario.with_changes(farm, output={"track": ["parquet", "csv"]}))
    out = folder / "out"
    write_outputs(result, str(out))  # no plot worker: the pictures are drawn in this process
    return result, out


def logged_ticks(result) -> np.ndarray:
    """The ticks a 1 Hz log keeps: the first of every second (`maps.PointLog.thin` of the tick indices)."""
    t = result.track["time_s"]
    index = np.arange(t.size, dtype=float)
    ticks = maps.PointLog(index, index, "EPSG:32632", applied=index, target=index, time_s=t)
    return ticks.thin(1.0).x.astype(int)


def test_timelog_holds_the_runs_time_span_and_rates(farm_run):
    result, out = farm_run
    (timelog,) = maps.read_timelogs(out / "taskdata")
    keep = logged_ticks(result)
    assert timelog.records == keep.size
    span_s = (timelog.time[-1] - timelog.time[0]).astype(float) / 1000.0
    t = result.track["time_s"]
    assert span_s == pytest.approx(t[keep[-1]] - t[keep[0]], abs=0.002)
    start = np.datetime64(round(result.started_unix * 1000), "ms")
    assert timelog.time[0] == start + np.timedelta64(round(result.track["time_s"][0] * 1000), "ms")
    # DDI 7 (actual) and 6 (setpoint) in mg/m^2 = kg/ha x 100, as logged (held where not logged)
    applied = timelog.value(7, hold=True) / 100.0
    width = result.control["width_on_m"][keep]
    want = np.where(width > 0, result.landing.applied_kg_ha[keep], 0.0)
    ok = np.isfinite(want)
    np.testing.assert_allclose(applied[ok], want[ok], atol=0.0051)
    np.testing.assert_allclose(timelog.value(6, hold=True) / 100.0, result.control["prescribed_kg_ha"][keep],
                               atol=0.0051)
    np.testing.assert_allclose(timelog.value(67) / 1000.0, width, atol=0.0005)
    log = maps.read_point_log(out / "taskdata")
    assert log.sections_on.shape == (keep.size, 4)
    np.testing.assert_allclose(log.sections_on.sum(axis=1) * 3.0, width)
    # DDI 161: each section's gate as section control switched it, not a strip rebuilt from the width
    np.testing.assert_array_equal(log.sections_on, result.control["sections_on"][keep])
    lon, lat = result.world.field.to_wgs84(result.track["x_m"][keep], result.track["y_m"][keep])
    np.testing.assert_allclose(log.x, lon, atol=1.5e-7)
    np.testing.assert_allclose(log.y, lat, atol=1.5e-7)
    assert (log.gnss_status == 8).all()  # simulate mode


def test_points_file_matches_the_timelog(farm_run):
    _, out = farm_run
    points = maps.read_point_log(out / "as_applied_points.gpkg")
    log = maps.read_point_log(out / "taskdata")
    assert points.crs.to_epsg() == 4326 and points.points == log.points and points.unit == "kg/ha"
    logged = np.isfinite(points.applied)  # a TimeLog holds the last value where a record has none
    np.testing.assert_allclose(points.applied[logged], log.applied[logged], atol=0.0051)
    np.testing.assert_allclose(points.x, log.x, atol=1.5e-7)


def test_rasters_prescription_nodata_outside_the_field_and_a_difference_map(farm_run):
    result, out = farm_run
    grid = result.world.grid
    rx = maps.read_map(out / "prescription.tif")
    np.testing.assert_allclose(rx.rates_kg_ha, grid.rates_kg_ha, rtol=1e-6)  # float32
    for name, description in (("prescription.tif", "application rate"), ("as_applied.tif", "as-applied"),
                              ("error.tif", "applied minus prescribed")):
        with rasterio.open(out / name) as ds:
            assert ds.dtypes[0] == "float32" and ds.nodata == -9999.0
            assert ds.descriptions[0] == description and ds.units[0] == "kg/ha"
            if name != "prescription.tif":
                valid = ds.read_masks(1) > 0
                assert (valid == result.in_field).all(), name  # nodata exactly outside the field
    error = maps.read_map(out / "error.tif")
    assert error.quantity == "difference" and np.nanmin(error.rates_kg_ha) < 0
    applied = maps.read_map(out / "as_applied.tif")
    np.testing.assert_allclose(error.rates_kg_ha, applied.rates_kg_ha - grid.rates_kg_ha, atol=1e-3)
    p = vrsim("map", "info", str(out / "error.tif"), "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["quantity"] == "difference"


def test_error_map_is_refused_as_a_prescription(farm_run, tmp_path):
    _, out = farm_run
    path = tmp_path / "again.toml"
    path.write_text(SCENARIO.replace('synthetic = "zones"', f'file = "{out / "error.tif"}"')
                    .replace("params = { n_zones = 5 }", "") % "")
    p = vrsim("run", str(path), "--quiet", "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "error.tif: holds differences of rates" in p.stderr, p.stderr


def test_track_csv_has_empty_fields_not_nan_and_the_parquet_nulls(farm_run):
    import pyarrow.parquet as pq

    result, out = farm_run
    text = (out / "track.csv").read_text()
    assert "nan" not in text.lower()
    with open(out / "track.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(result.track["time_s"])
    applied = np.array([float(r["applied_kg_ha"]) if r["applied_kg_ha"] else np.nan for r in rows])
    missing = np.isnan(result.landing.applied_kg_ha)
    assert missing.any()  # sections off: no applied rate
    assert (np.isnan(applied) == missing).all()
    columnar = pq.read_table(out / "track.parquet").column("applied_kg_ha")
    assert (np.asarray(columnar.is_null()) == missing).all()
    np.testing.assert_allclose(applied[~missing], result.landing.applied_kg_ha[~missing], atol=0.005)
    assert {r["implement_on"] for r in rows} == {"0", "1"}


def test_summary_shows_the_parameters_as_run_and_the_report_the_settings(farm_run):
    result, out = farm_run
    config = json.loads((out / "summary.json").read_text())["scenario_config"]
    assert config["plant"]["shaft_rpm_max"] == 120.0  # the implement's, as the plant ran it
    assert config["plant"]["transmission_ratio"] == config["implement"]["transmission_ratio"]
    assert config["output"]["log_rate_hz"] == 1.0
    page = (out / "report.html").read_text()
    for text in ("Controller", "Implement", "GNSS", "Speed sensor", "incremental", "rtk", "SUMO (libsumo)",
                 "1.28.0", "<td>seed</td><td>4</td>", "<td>shaft_rpm_max</td><td><code>120.0</code></td>"):
        assert text in page, text
    for m in METRICS:
        assert f"<code>{m.key}</code>" in page and m.description.replace("'", "&#x27;") in page, m.key


def test_round_trip_run_timelog_evaluate(farm_run):
    """`vrsim evaluate taskdata/ --prescription prescription.tif --delay-s D` gives, within 1 %, the point
    figures of the run's own arrays at the logged ticks: applied rate per tick against the prescription
    where it lands (`Landing.prescribed_kg_ha`, at the middle of the tick's strip: D = delivery delay +
    half a tick). The run's map figures (over cells, area-weighted) differ in definition and are not
    compared. (The map's 2.2 m cells keep the swaths off cell edges: on an edge, the log's 1 cm
    positions pick either cell.)"""
    result, out = farm_run
    sc = result.world.scenario
    delay = sc.implement.delivery_delay_s + sc.timing.control_period_s / 2
    p = vrsim("evaluate", str(out / "taskdata"), "--prescription", str(out / "prescription.tif"),
              "--delay-s", str(delay), "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    keep = logged_ticks(result)[:-1]  # the last record has no landing point within the log
    track = result.track
    width = result.control["width_on_m"][keep]
    applied = np.where(width > 0, result.landing.applied_kg_ha[keep], 0.0)
    compared = np.asarray(track["implement_on"], bool)[keep] & (width > 0)
    x, y = track["x_m"][keep], track["y_m"][keep]
    distance = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    own = point_metrics(applied, result.landing.prescribed_kg_ha[keep], track["time_s"][keep], distance,
                        compared)
    print("evaluate:", got, "\nrun arrays:", own)
    assert got["unit"] == "kg/ha"
    assert got["points"] == pytest.approx(own.points, rel=0.01)
    assert got["transitions"] == pytest.approx(own.transitions, rel=0.05, abs=1) and own.transitions > 5
    for key in ("applied_mean", "target_mean", "mae", "rmse", "within_5pct_pct", "within_10pct_pct",
                "transition_time_s_mean", "transition_distance_m_mean"):
        assert got[key] == pytest.approx(getattr(own, key), rel=0.01), key
    for key in ("bias", "mass_balance_pct"):  # near zero: 1 % of the mean target, in kg/ha or %
        scale = own.target_mean if key == "bias" else 100.0
        assert got[key] == pytest.approx(getattr(own, key), abs=0.01 * scale), key
    p = vrsim("evaluate", str(out / "taskdata"), "--prescription", str(out / "prescription.tif"), "--json")
    assert json.loads(p.stdout)["mae"] > 1.05 * got["mae"]  # without the delay, each step is 0.8 s off


def test_pictures_drawn_here_and_by_the_worker(farm_run, tmp_path):
    from PIL import Image

    from vrsim.services.outputs import plots
    from vrsim.services.outputs.plot_worker import PlotWorker

    result, out = farm_run
    worker = PlotWorker().start()
    try:
        worker.submit("draw_maps", plots.map_picture(result), str(tmp_path / "map.png"))
        worker.submit("print_money", None, str(tmp_path / "x.png"))
        worker.result()
        with pytest.raises(RuntimeError, match="print_money .*x.png: ValueError: unknown drawing"):
            worker.result()
    finally:
        worker.close()
    for path in (out / "map.png", out / "timeseries.png", tmp_path / "map.png"):
        with Image.open(path) as im:
            assert im.size[0] > 900, path
    assert "data:image/png;base64" in (out / "report.html").read_text()


class _EndsItsProcess:
    """A picture whose unpickling ends the process that draws it (a crash without a reply)."""

    def __reduce__(self):
        return os._exit, (3,)


def test_plot_worker_draws_each_job_in_its_own_process_and_survives_one_that_ends(tmp_path):
    from PIL import Image

    from vrsim.services.outputs.plot_worker import PlotWorker
    from vrsim.services.outputs.plots import SeriesPicture

    t = np.arange(0.0, 60.0, 0.05)
    series = SeriesPicture(t, 100 + 0 * t, 99 + 0 * t, 150 + 0 * t, 149 + 0 * t, "a minute", "kg/ha")
    worker = PlotWorker().start()
    try:
        worker.submit("draw_timeseries", series, str(tmp_path / "a.png"))
        worker.submit("draw_timeseries", _EndsItsProcess(), str(tmp_path / "b.png"))
        worker.submit("draw_timeseries", series, str(tmp_path / "c.png"))
        worker.result()
        with pytest.raises(RuntimeError, match=r"job 2: the forked _drawn ended without a result "
                                               r"\(exit code 3\)"):
            worker.result()
        worker.result()
        drawers = _children(worker.proc.pid)
    finally:
        worker.close()
    for name in ("a.png", "c.png"):
        with Image.open(tmp_path / name) as im:
            assert im.size[0] > 900, name
    assert not (tmp_path / "b.png").exists()
    assert drawers == []  # every drawing process reaped once it replied


def test_a_reply_nobody_asked_for_yet_does_not_hold_up_the_next_drawing(tmp_path):
    """A PNG drawn into memory is larger than the pipe: the worker must not wait for the caller's
    `result` before it takes the next job (map.png waited for the run's other files so)."""
    from vrsim.services.outputs.plot_worker import PlotWorker
    from vrsim.services.outputs.plots import SeriesPicture

    t = np.arange(0.0, 60.0, 0.05)
    noisy = SeriesPicture(t, 100 + 10 * np.sin(t), 99 + 10 * np.cos(3 * t), 150 + 0 * t, 149 + 0 * t,
                          "a minute", "kg/ha")
    worker = PlotWorker().start()
    try:
        worker.submit("draw_timeseries", noisy, None)                    # its reply: the PNG's bytes
        _wait_for(lambda: _children(worker.proc.pid))         # drawing it
        _wait_for(lambda: not _children(worker.proc.pid))     # drawn, its reply sent or stuck in the pipe
        worker.submit("draw_timeseries", noisy, str(tmp_path / "next.png"))
        deadline = time.monotonic() + 30.0
        while not (tmp_path / "next.png").exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert (tmp_path / "next.png").exists()   # drawn before anyone read the first reply
        png = worker.result()
        assert len(png) > 1 << 16 and png.startswith(b"\x89PNG")  # more than the pipe holds
        assert worker.result() == str(tmp_path / "next.png")
    finally:
        worker.close()


def _wait_for(condition, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def _children(pid: int) -> list[int]:
    with open(f"/proc/{pid}/task/{pid}/children") as fh:
        return [int(c) for c in fh.read().split()]


def test_output_options(tmp_path):
    folder = str(tmp_path)
    out = tmp_path / "o"
    p = vrsim("run", scenario_file(folder, 'log_rate_hz = 4.0\npoints = "shp"\nplots = false'), "--quiet",
              "--out", str(out))
    assert p.returncode == 0, p.stderr
    (timelog,) = maps.read_timelogs(out / "taskdata")
    points = maps.read_point_log(out / "as_applied_points.zip")
    assert points.points == timelog.records
    assert np.median(np.diff(timelog.time).astype(float)) == 250.0  # ms
    p = vrsim("run", scenario_file(folder, 'points = "none"'), "--quiet", "--out", str(out))
    assert p.returncode == 0, p.stderr  # a rerun into the same folder replaces the run's taskdata/
    assert not (out / "as_applied_points.gpkg").exists()
    (out / "taskdata" / "notes.txt").write_text("mine")
    p = vrsim("run", scenario_file(folder), "--quiet", "--out", str(out))
    assert p.returncode == 2 and "already holds a TASKDATA.XML" in p.stderr, p.stderr
    for line, needle in (("log_rate_hz = 0.0", "log_rate_hz must be > 0 and <= the control rate (20 Hz), "
                                               "got 0.0"),
                         ("log_rate_hz = 25.0", "got 25.0"),
                         ('points = "kml"', "[output] points must be one of gpkg, shp, none, got 'kml'")):
        p = vrsim("run", scenario_file(folder, line), "--quiet", "--out", str(tmp_path / "x"))
        assert p.returncode == 2 and needle in p.stderr and "farm.toml" in p.stderr, p.stderr


def test_evaluate_john_deere_export(shared_dir, tmp_path):
    path = os.path.join(shared_dir, DEERE)
    p = vrsim("evaluate", path, "--json", "--out", str(tmp_path / "ev"))
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    print(got)
    assert got["points"] == 780 and got["unit"] == "gal/ac"
    assert got["applied_mean"] == pytest.approx(10.009, abs=0.001)
    assert got["target_mean"] == pytest.approx(9.996, abs=0.001)
    assert got["within_10pct_pct"] > 99.0
    error = maps.read_map(tmp_path / "ev" / "error.tif")
    assert error.unit == "gal/ac" and error.quantity == "difference"
    page = (tmp_path / "ev" / "report.html").read_text()
    assert "gal/ac" in page and "data:image/png;base64" in page
    assert json.loads((tmp_path / "ev" / "evaluation.json").read_text()) == got
    p = vrsim("evaluate", path)
    assert p.returncode == 0 and "Points compared" in p.stdout and "gal/ac" in p.stdout
    # --field: a boundary over the southern half of the points keeps about half of them
    log = maps.read_point_log(path)
    west, east = log.x.min() - 0.001, log.x.max() + 0.001
    south, mid = log.y.min() - 0.001, float(np.median(log.y))
    ring = [[west, south], [east, south], [east, mid], [west, mid], [west, south]]
    boundary = tmp_path / "south.geojson"
    boundary.write_text(json.dumps({"type": "Feature", "properties": {},
                                    "geometry": {"type": "Polygon", "coordinates": [ring]}}))
    p = vrsim("evaluate", path, "--field", str(boundary), "--json")
    assert p.returncode == 0, p.stderr
    assert 300 < json.loads(p.stdout)["points"] < 480
    p = vrsim("evaluate", path, "--field", str(tmp_path / "none.geojson"))
    assert p.returncode == 2 and "none.geojson" in p.stderr, p.stderr


def test_evaluate_bad_input_exits_2_naming_file_and_field(shared_dir, tmp_path, farm_run):
    _, out = farm_run
    deere = os.path.join(shared_dir, DEERE)
    not_a_log = tmp_path / "notes.gpkg"
    not_a_log.write_text("not a GeoPackage")
    cases = [
        ((str(tmp_path / "nope.zip"),), ["nope.zip", "no such file"]),
        ((str(not_a_log),), ["notes.gpkg", "cannot read"]),
        ((str(out / "prescription.tif"),), ["prescription.tif", "as-applied log must be"]),
        ((deere, "--rate-field", "Nope"), ["onehertz.zip", "'Nope'", "applied rate"]),
        ((str(out / "taskdata"), "--rate-field", "0x0002"), ["taskdata", "DDI 0002"]),
        ((deere, "--prescription", str(out / "prescription.tif")), ["gal/ac", "density"]),
    ]
    for args, needles in cases:
        p = vrsim("evaluate", *args)
        assert p.returncode == 2, (args, p.stdout, p.stderr)
        assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
        for needle in needles:
            assert needle in p.stderr, (needle, p.stderr)


def test_points_and_taskdata_of_one_run_evaluate_alike(tmp_path):
    """`vrsim run --out`'s as_applied_points.gpkg and its taskdata/ give the same points and figures (the
    TimeLog rounds rates to 0.01 kg/ha), and both leave out the same records for the same reasons."""
    out = tmp_path / "out"
    p = vrsim("run", scenario_file(str(tmp_path)), "--quiet", "--out", str(out))
    assert p.returncode == 0, p.stderr
    got = []
    for log in (out / "as_applied_points.gpkg", out / "taskdata"):
        p = vrsim("evaluate", str(log), "--json")
        assert p.returncode == 0, p.stderr
        got.append(json.loads(p.stdout))
    points, timelog = got
    print(points, timelog)
    assert points["points"] == timelog["points"] > 0
    assert points["excluded"] == timelog["excluded"] and sum(points["excluded"].values()) > 0
    for key in ("applied_mean", "target_mean", "mae", "rmse", "bias"):
        assert points[key] == pytest.approx(timelog[key], abs=0.01), key


def test_evaluate_leaves_out_target_0_and_sections_off(tmp_path):
    """A layer with target-0 records and records with no width in use: `vrsim evaluate` gives what numpy
    gives over the records with a target above 0 and a section on; --include-zero-target adds the
    target-0 records back."""
    import pyogrio
    import shapely

    rng = np.random.default_rng(7)
    n = 400
    target = np.where(rng.random(n) < 0.2, 0.0, rng.choice([120.0, 150.0, 180.0], n))
    applied = np.where(target > 0, target + rng.normal(0, 5, n), rng.uniform(0, 300, n))
    width = np.where(rng.random(n) < 0.1, 0.0, 12.0)
    lon, lat = 10.0 + np.arange(n) * 2e-5, np.full(n, 52.0)
    stamps = np.datetime64("2026-05-01T10:00:00", "ms") + np.arange(n).astype("timedelta64[s]")
    path = tmp_path / "zeros.gpkg"
    pyogrio.raw.write(str(path), shapely.to_wkb(shapely.points(lon, lat)),
                      [stamps, applied, target, width, np.full(n, "kg/ha", dtype=object)],
                      ["time", "AppliedRate", "TargetRate", "width_m", "rate_unit"], driver="GPKG",
                      geometry_type="Point", crs="EPSG:4326")
    p = vrsim("evaluate", str(path), "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    keep = (target > 0) & (width > 0)
    error = applied[keep] - target[keep]
    assert got["points"] == keep.sum()
    assert got["mae"] == pytest.approx(np.abs(error).mean())
    assert got["rmse"] == pytest.approx(np.sqrt((error ** 2).mean()))
    assert got["bias"] == pytest.approx(error.mean())
    assert got["applied_mean"] == pytest.approx(applied[keep].mean())
    assert got["excluded"]["no_section_on"] == (width == 0).sum()
    assert got["excluded"]["target_0"] == ((width > 0) & (target == 0)).sum()
    p = vrsim("evaluate", str(path), "--json", "--include-zero-target")
    assert json.loads(p.stdout)["points"] == (width > 0).sum()
    p = vrsim("evaluate", str(path))
    assert "Records left out" in p.stdout and "target 0" in p.stdout, p.stdout
