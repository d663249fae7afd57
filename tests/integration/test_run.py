"""vrsim run end to end: real SUMO, real files, through the real executable where it matters."""

import dataclasses
import json
import os
import re
import subprocess

import numpy as np
import pytest
import rasterio
from PIL import Image

from tests.conftest import VRSIM
from vrsim.maps import write_map
from vrsim.services.outputs.encode import dumps_text
from vrsim.services.sim import run, scenario
from vrsim.services.sim.core import ControlCore
from vrsim.services.sim.world import build_world

QUICK = """
name = "quick"
seed = 5
[field]
rectangle = { width_m = 72.0, length_m = 150.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "%s"
cell_size_m = 2.0
params = %s
[tractor]
speed_variation_pct = %s
[output]
plots = %s
html = %s
"""


def quick(tmp_path, kind="zones", params="{ n_zones = 4 }", variation=5.0, plots=True, name="q.toml"):
    path = tmp_path / name
    flag = "true" if plots else "false"
    path.write_text(QUICK % (kind, params, variation, flag, flag))
    return str(path)


def vrsim(*args):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=300)


def test_run_json_writes_every_output_and_they_open(tmp_path):
    out = tmp_path / "out"
    p = vrsim("run", quick(tmp_path), "--json", "--quiet", "--out", str(out))
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    for key in ("scenario", "field_area_ha", "sim_time_s", "wall_time_s", "ticks", "realtime_factor",
                "prescribed_kg", "applied_kg", "mass_balance_pct", "mae_kg_ha", "rmse_kg_ha", "bias_kg_ha",
                "within_5pct_area_pct", "within_10pct_area_pct", "transition_time_s_mean",
                "transition_time_s_p95", "transition_distance_m_mean", "transition_distance_m_p95",
                "off_target_kg", "coverage_pct"):
        assert key in summary
    assert summary["field_area_ha"] == pytest.approx(1.08)
    assert summary["ticks"] > 1000 and summary["coverage_pct"] > 90
    for name in ("map.png", "timeseries.png"):
        with Image.open(out / name) as im:
            im.load()
            assert im.size[0] > 400
    for name in ("as_applied.tif", "error.tif"):
        with rasterio.open(out / name) as ds:
            data = ds.read(1)
            assert ds.crs is not None and np.isfinite(data).any()
    with rasterio.open(out / "as_applied.tif") as ds:
        assert np.nanmax(ds.read(1)) > 50.0  # product was applied
    page = (out / "report.html").read_text()
    for ref in re.findall(r'(?:src|href)="([^"]+)"', page):
        assert ref.startswith("data:") or (out / ref).is_file(), ref
    assert "Mean absolute error" in page
    import pyarrow.parquet as pq

    track = pq.read_table(out / "track.parquet")   # the default track file (a scenario's own)
    assert track.column_names[:3] == ["time_s", "lat", "lon"] and track.num_rows == summary["ticks"]
    assert not (out / "track.csv").exists()
    saved = json.loads((out / "summary.json").read_text())
    assert saved["mae_kg_ha"] == summary["mae_kg_ha"]


def test_readable_summary(tmp_path):
    p = vrsim("run", quick(tmp_path, plots=False), "--quiet", "--out", str(tmp_path / "o"))
    assert p.returncode == 0, p.stderr
    assert "Mean absolute error" in p.stdout and "kg/ha" in p.stdout


def test_uniform_map_at_constant_speed_balances_within_one_percent(tmp_path):
    """Metering, plant and landing conserve product: what lands equals 150 kg/ha over the strips the
    implement swept while on (overlaps counted twice, as the product is) to within 1 %."""
    sc = scenario.load(quick(tmp_path, "uniform", "{ rate_kg_ha = 150.0 }", variation=0.0, plots=False))
    result = run(sc)
    on = np.asarray(result.track["implement_on"], bool)
    swept_ha = (result.landing.strip_length_m[on] * sc.implement.width_m).sum() / 1e4
    asked_kg = 150.0 * swept_ha
    assert result.summary["applied_kg"] == pytest.approx(asked_kg, rel=0.01)
    assert result.as_applied.applied_kg.sum() + result.as_applied.outside_kg == pytest.approx(
        result.summary["applied_kg"], rel=1e-9)
    # Against the prescription over the area worked once, headland overlap adds a little more.
    assert abs(result.summary["mass_balance_pct"]) < 2.5
    assert result.summary["within_10pct_area_pct"] > 90.0


def with_nodata_hole(tmp_path) -> str:
    """The quick scenario on a GeoTIFF copy of its map with a nodata hole in the field, policy hold."""
    sc = scenario.load(quick(tmp_path, plots=False))
    grid = build_world(sc).grid
    rates = grid.rates_kg_ha.copy()
    rates[40:50, 20:30] = np.nan
    write_map(dataclasses.replace(grid, rates_kg_ha=rates), str(tmp_path / "rx.tif"))
    text = open(sc.source).read().replace('synthetic = "zones"', 'file = "rx.tif"\npolicy = "hold"')
    path = tmp_path / "hold.toml"
    path.write_text(text.replace("params = { n_zones = 4 }\n", ""))
    return str(path)


def with_tuned_smith(tmp_path) -> str:
    """The quick scenario with a Smith predictor, the auto look-ahead and its auto-tune."""
    path = quick(tmp_path, plots=False)
    with open(path, "a") as fh:
        fh.write('[controller]\nkind = "smith"\nlook_ahead_s = "auto"\nlook_ahead_tune = 0.5\n')
    return path


def with_uneven_flow(tmp_path) -> str:
    path = quick(tmp_path, plots=False, name="flow.toml")
    with open(path, "a") as fh:
        fh.write("[product]\nflow_cv_pct = 8.0\ncalibration_error_pct = 4.0\n")
    return path


def with_response(tmp_path) -> str:
    """The quick scenario with a machine's fitted response: dead time, pass-start preset and opening
    transient (`vehicle.response`), all following the passes across batches."""
    path = quick(tmp_path, plots=False, name="response.toml")
    with open(path, "a") as fh:
        fh.write("[response]\ndead_time_s = 0.7\nstartup_speed_m_s = 3.5\nstartup_hold_s = 2.0\n"
                 "opening_peak_pct = 50.0\nopening_time_constant_s = 1.2\ncalibration_error_pct = 3.0\n")
    return path


@pytest.mark.parametrize("policy", ["off", "hold", "tuned", "flow", "response"])
def test_batch_by_batch_core_matches_the_staged_run(tmp_path, policy):
    """The controller service calls ControlCore.run_track on each lockstep batch (one tick in real-time
    mode), carrying its state over; vrsim run calls it once on the whole track: same numbers (also
    with the look-ahead tune, whose updates must fall on the same ticks however the track is cut, and
    with a product whose flow varies revolution to revolution, its shaft position carried over)."""
    # Only the case's own file is written (each helper writes its own name or q.toml).
    path = {"off": lambda: quick(tmp_path, plots=False), "hold": lambda: with_nodata_hole(tmp_path),
            "tuned": lambda: with_tuned_smith(tmp_path), "flow": lambda: with_uneven_flow(tmp_path),
            "response": lambda: with_response(tmp_path)}[policy]()
    sc = scenario.load(path)
    assert sc.map.policy == ("hold" if policy == "hold" else "off")
    assert (sc.product.flow_cv_pct > 0) == (policy == "flow")
    result = run(sc)
    core = ControlCore(result.world.grid, sc, result.world.field.polygon, result.world.path)
    t = result.track
    n = len(t["time_s"])
    # Single ticks first (real-time mode), then lockstep batches of uneven sizes.
    sizes = [1] * 200 + [7, 50, 333, 1]
    cuts = np.cumsum(sizes)
    cuts = np.append(cuts[cuts < n], np.arange(cuts[-1], n, 50)[1:])
    parts = []
    for i, part in enumerate(np.split(np.arange(n), cuts)):
        if part.size:
            parts.append(core.run_track(result.measured_x_m[part], result.measured_y_m[part],
                                        t["heading_rad"][part], result.measured_speed_m_s[part],
                                        t["implement_on"][part], t["s_m"][part]))
        if i % 97 == 0:   # now and then a fresh core that resumes from the state (after JSON)
            saved = json.loads(dumps_text(core.state()))
            core = ControlCore(result.world.grid, sc, result.world.field.polygon, result.world.path)
            core.set_state(saved)
    batched = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    if policy == "tuned":
        assert core.tuner.updates > 3 and core.look_ahead_s != core.tuner.known_delay_s
    if policy == "response":   # the passes' clock was carried: some pass started within a batch
        assert sc.response.follows_passes and core.passes.open_ticks < np.inf
    np.testing.assert_allclose(batched["shaft_rpm"], result.control["shaft_rpm"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(batched["metered_kg"], result.control["metered_kg"], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(batched["prescribed_kg_ha"], result.control["prescribed_kg_ha"])
    np.testing.assert_array_equal(batched["sections_on"], result.control["sections_on"])
    assert result.control["sections_on"].any() and not result.control["sections_on"].all()
    assert len(parts) > 200 and batched["metered_kg"].sum() > 0
    if policy == "hold":  # the hole was crossed, and held rates filled it
        looked_up = result.world.grid.lookup(batched["landing_x_m"], batched["landing_y_m"]).rate_kg_ha
        held = np.isnan(looked_up)
        assert held.sum() > 20 and (batched["prescribed_kg_ha"][held] > 0).all()


@pytest.mark.parametrize("edit, message", [
    (("[tractor]", "[tractor]\nworking_speed_m_s = \"fast\""), "[tractor] working_speed_m_s must be number"),
    (("[tractor]", "[tractor]\nwarp_drive = 1"), "unknown key 'warp_drive'"),
    (("[field]", "[field]\nturn_radius_m = -3.0"), "turn_radius_m must be > 0, got -3.0"),
    (("synthetic = \"zones\"", "synthetic = \"plasma\""), "synthetic must be one of"),
    (("[output]", "[implement]\nwidth_m = -12.0\n[output]"), "width_m"),
    (("[field]", "[fieeld]\n[field]"), "unknown key 'fieeld'"),
    (("{ n_zones = 4 }", "{ n_zones = 4, slope = 2 }"), "[map.params] unknown key 'slope'"),
    (("{ n_zones = 4 }", "{ rate_range_kg_ha = [1.0, 2.0, 3.0] }"), "do not fit synthetic 'zones'"),
])
def test_bad_scenario_exits_2_naming_file_key_and_value(tmp_path, edit, message):
    path = quick(tmp_path)
    text = open(path).read().replace(*edit, 1)
    open(path, "w").write(text)
    p = vrsim("run", path, "--quiet", "--out", str(tmp_path / "o"))
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    assert path in p.stderr and message in p.stderr, p.stderr


def test_missing_scenario_and_bad_toml(tmp_path):
    p = vrsim("run", str(tmp_path / "nope.toml"))
    assert p.returncode == 2 and "no such scenario file" in p.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    p = vrsim("run", str(bad))
    assert p.returncode == 2 and "not valid TOML" in p.stderr and "Traceback" not in p.stderr


def test_map_that_misses_the_field_is_refused(tmp_path, shared_dir):
    zipped = os.path.join(shared_dir, "data", "isoxml", "isoxml-js-task_with_grid.zip")
    path = tmp_path / "far.toml"
    path.write_text(QUICK.replace('synthetic = "%s"', f'file = "{zipped}"').replace("params = %s\n", "")
                    % (5.0, "false", "false"))
    p = vrsim("run", str(path), "--quiet", "--out", str(tmp_path / "o"))
    assert p.returncode == 2, p.stderr
    assert "overlap" in p.stderr and "Traceback" not in p.stderr
