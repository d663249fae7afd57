"""The edges of rate units, through real runs: the machine check, the pictures and compare's tables in
the map's unit; a seeds/ac GeoTIFF run with the seeds' mass (refused without it); the map service
serving a unitless file given ``--unit``, its replies carrying ``rate`` and ``rate_unit``."""

import json
import os

import numpy as np
import pytest

from tests.integration.test_rate_units import (
    LB_AC,
    SOUTH,
    WEST,
    band_unit,
    one_line_exit_2,
    scenario,
    vrsim,
    write_tif,
)
from vrsim.maps import read_map, read_taskdata_log
from vrsim.maps.units import convert_rate
from vrsim.services.sim import scenario as scenario_mod

TKW_G = 320.0  # maize, g per thousand seeds
SEEDS_AC = float(convert_rate(1.0, "seeds/ac", "kg/ha", seed_mass_g=TKW_G / 1000))  # kg/ha in one seed/ac


def test_machine_check_in_the_maps_unit_text_and_json(tmp_path):
    scen = scenario(tmp_path, write_tif(tmp_path / "rx.tif", "lb/ac"))
    p = vrsim("run", scen, "--check")
    assert p.returncode == 0, p.stderr
    assert "the meter can apply the map: 100-150 lb/ac at" in p.stdout and "kg/ha" not in p.stdout
    doc = json.loads(vrsim("run", scen, "--check", "--json").stdout)
    assert doc["rate_unit"] == "lb/ac"
    assert doc["in_rate_unit"] == {"rate_min": pytest.approx(100), "rate_max": pytest.approx(150)}
    assert doc["rate_max_kg_ha"] == pytest.approx(150 * LB_AC)   # the kg/ha keys stay


def test_default_machine_check_stays_in_kg_ha():
    doc = json.loads(vrsim("run", "--check", "--json").stdout)
    assert doc["rate_unit"] == "kg/ha"
    assert doc["in_rate_unit"] == {"rate_min": doc["rate_min_kg_ha"], "rate_max": doc["rate_max_kg_ha"]}
    assert " kg/ha at " in vrsim("run", "--check").stdout


def test_pictures_and_compare_show_the_maps_unit(tmp_path):
    from vrsim.services.outputs import compare as compare_out
    from vrsim.services.outputs import plots
    from vrsim.services.sim.compare import compare

    sc = scenario_mod.load(str(scenario(tmp_path, write_tif(tmp_path / "rx.tif", "lb/ac"))))
    comparison = compare(sc, ["pid", "ff_pi"])
    result = comparison.results[0]
    pic = plots.map_picture(result)
    assert pic.unit == "lb/ac" and np.nanmax(pic.prescribed) == pytest.approx(150, rel=1e-6)
    assert f"MAE {result.summary['in_rate_unit']['mae']:.1f} lb/ac" in pic.title
    assert pic.error_floor == pytest.approx(1 / LB_AC)
    series = plots.series_picture(result)
    assert series.unit == "lb/ac" and np.nanmax(series.prescribed) == pytest.approx(150, rel=1e-6)
    plots.draw_maps(pic, str(tmp_path / "map.png"))
    plots.draw_timeseries(series, str(tmp_path / "timeseries.png"))
    assert os.path.getsize(tmp_path / "map.png") > 0 and os.path.getsize(tmp_path / "timeseries.png") > 0
    text = compare_out.table_text(comparison)
    assert "[lb/ac]" in text and "[kg/ha]" not in text
    mae = compare_out._cell(result.summary["in_rate_unit"]["mae"])
    assert mae in text.splitlines()[3]
    page = compare_out._table_html(comparison)
    assert "<br>lb/ac</th>" in page and "kg/ha" not in page


def write_seeds_tif(path):
    return write_tif(path, "seeds/ac", low=25000.0, high=40000.0)


def test_a_seeds_ac_geotiff_runs_with_the_seeds_mass_and_every_output_states_its_unit(tmp_path):
    scen = scenario(tmp_path, write_seeds_tif(tmp_path / "rx.tif"),
                    extra=f'[product]\nname = "maize"\nthousand_seed_mass_g = {TKW_G}')
    out = tmp_path / "out"
    p = vrsim("run", scen, "--json", "--quiet", "--out", out)
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["rate_unit"] == "seeds/ac"
    assert s["in_rate_unit"]["mae"] == pytest.approx(s["mae_kg_ha"] / SEEDS_AC, rel=1e-12)
    # 25 000-40 000 seeds/ac of 0.32 g seeds: 19.8-31.6 kg/ha metered as mass.
    assert abs(s["mass_balance_pct"]) < 5 and s["prescribed_kg"] > 0
    for name in ("prescription.tif", "as_applied.tif", "error.tif"):
        assert band_unit(out / name) == "seeds/ac", name
    rx = read_map(out / "prescription.tif")
    assert rx.unit == rx.map_unit == "seeds/ac"
    assert np.nanmax(rx.rates_kg_ha) == pytest.approx(40000, rel=1e-6)
    log = read_taskdata_log(out / "taskdata")  # count per area: DDI 11 and 12, read in seeds/ha
    seeds_ha = float(convert_rate(40000, "seeds/ac", "seeds/ha"))
    assert log.unit == "seeds/ha" and np.nanmax(log.target) == pytest.approx(seeds_ha, abs=10)
    html = (out / "report.html").read_text()
    assert "seeds/ac" in html and " seeds/ac at " in html   # the figures and the machine check
    p = vrsim("run", scen, "--quiet", "--out", tmp_path / "out2")
    assert "25000-40000 seeds/ac at" in p.stdout
    line = next(row for row in p.stdout.splitlines() if "Mean absolute error" in row)
    assert line.endswith("seeds/ac")


def test_a_count_map_without_the_seeds_mass_is_refused_naming_the_key(tmp_path):
    scen = scenario(tmp_path, write_seeds_tif(tmp_path / "rx.tif"))
    one_line_exit_2(vrsim("run", scen, "--quiet", "--out", tmp_path / "out"), f"{scen}: [map]",
                    "a count rate (seeds/ac) runs as a mass rate only with the product's seed mass",
                    "[product] thousand_seed_mass_g")
    bad = scenario(tmp_path, write_seeds_tif(tmp_path / "rx.tif"), name="bad",
                   extra="[product]\nthousand_seed_mass_g = -3")
    one_line_exit_2(vrsim("run", bad, "--quiet", "--out", tmp_path / "out"), "[product]",
                    "thousand_seed_mass_g must be a number in (0, 5000] g, got -3")


# ------------------------------------------------------------------------------------------ map service
@pytest.fixture(scope="module")
def lb_ac_net(tmp_path_factory):
    """serve all with a unitless GeoTIFF (lb/ac rates) as the fixed map, given ``--unit lb/ac``."""
    from tests.integration.test_services_support import ServeAll

    folder = tmp_path_factory.mktemp("svc_units")
    tif = write_tif(folder / "rx.tif", None)
    server = ServeAll(str(folder), "--map", str(tif), "--unit", "lb/ac")
    try:
        server.wait_ready()
        yield server
    finally:
        assert server.stop() == 0, server.output()


def test_serve_map_with_unit_replies_in_the_maps_unit(lb_ac_net):
    ok, info = lb_ac_net.query("vrsim/map/info")
    assert ok and info["rate_unit"] == "lb/ac" and info["max_rate"] == pytest.approx(150), info
    lat, lon = SOUTH + 0.001, WEST + 0.0019   # the east zone: 150 lb/ac
    ok, got = lb_ac_net.query(f"vrsim/map/rate?lat={lat!r};lon={lon!r}")
    assert ok and got["rate_unit"] == "lb/ac" and got["rate"] == pytest.approx(150), got
    assert got["rate_kg_ha"] == pytest.approx(150 * LB_AC)
    body = json.dumps({"lat": [lat, lat, 0.0], "lon": [lon, WEST + 0.0001, 0.0]}).encode()
    ok, got = lb_ac_net.query("vrsim/map/rate", body)
    assert ok and [g["rate_unit"] for g in got] == ["lb/ac"] * 3
    assert [g["rate"] for g in got[:2]] == [pytest.approx(150), pytest.approx(100)] and got[2]["rate"] is None
    assert got[1]["rate_kg_ha"] == pytest.approx(100 * LB_AC) and not got[2]["inside"]


def test_serve_map_of_a_unitless_file_without_unit_is_refused_in_one_line(tmp_path):
    tif = write_tif(tmp_path / "rx.tif", None)
    p = vrsim("serve", "map", "--map", tif, "--listen", "tcp/127.0.0.1:1", "--insecure")
    # One line after --insecure's warning.
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    error = p.stderr.strip().splitlines()[1:]
    assert len(error) == 1 and f"{tif}: the map does not state the unit of its rates" in error[0], p.stderr
    assert "--unit" in error[0]


def test_the_web_legend_reads_in_the_maps_unit():
    from vrsim.services.bus.web import picture

    info = {"min_rate_kg_ha": 100 * LB_AC, "max_rate_kg_ha": 150 * LB_AC, "rate_unit": "lbs/ac",
            "min_rate": 100.0, "max_rate": 150.0}
    colours = picture.scale(info)
    assert (colours["vmin"], colours["vmax"], colours["unit"]) == (100.0, 150.0, "lb/ac")
    assert colours["vmax_kg_ha"] == pytest.approx(150 * LB_AC)   # painted in kg/ha, as the live layer
    # The bus is untrusted: a unit that is none, or a range not given, leaves the legend in kg/ha.
    long = "kg/" + "ha" * 40
    for bad in ({"rate_unit": "<b>"}, {"rate_unit": 3}, {"rate_unit": long}, {"max_rate": "150"}):
        colours = picture.scale({**info, **bad})
        assert colours["unit"] == "kg/ha" and colours["vmax"] == pytest.approx(150 * LB_AC)


def test_sweep_rows_and_report_in_the_maps_unit(tmp_path):
    from vrsim.services.outputs.sweep_results import _read_rows

    scenario(tmp_path, write_tif(tmp_path / "rx.tif", "lb/ac"), name="q")
    (tmp_path / "s.toml").write_text('scenarios = ["q.toml"]\nseeds = [1]\n[axes]\n'
                                     '"implement.delivery_delay_s" = [0.6, 0.9]\n'
                                     '[report]\npareto = ["mae_kg_ha", "within_10pct_area_pct"]\n')
    p = vrsim("sweep", tmp_path / "s.toml", "--no-dashboard", "--json", "--quiet", "--workers", "1",
              "--out", tmp_path / "out")
    assert p.returncode == 0, p.stderr
    rows = _read_rows(str(tmp_path / "out" / "results.parquet"))
    assert [r["rate_unit"] for r in rows] == ["lb/ac"] * 2
    for row in rows:
        assert row["mae_in_rate_unit"] == pytest.approx(row["mae_kg_ha"] / LB_AC, rel=1e-12)
    report = (tmp_path / "out" / "report.html").read_text()
    assert "Mean absolute error [lb/ac]" in report and "[kg/ha]" not in report
    best = min(r["mae_in_rate_unit"] for r in rows)
    assert f"<td>{best:,.3g}</td>" in report   # the best MAE, in lb/ac


def test_a_sprayers_machine_check_names_the_maps_unit_beside_l_ha(tmp_path):
    from tests.integration.test_rate_units import GAL_AC, write_gal_ac_shapefile

    extra = '[product]\nform = "liquid"\ndensity_kg_l = 1.2\n'
    scen = scenario(tmp_path, write_gal_ac_shapefile(tmp_path / "rx"), extra=extra)
    text = scen.read_text().replace("[implement]\n", '[implement]\nkind = "sprayer"\nnozzle = "06"\n')
    scen.write_text(text)
    p = vrsim("run", scen, "--check")
    assert p.returncode == 3, p.stderr   # '06' nozzles need 5.5 m/s or more for 10 gal/ac: it cannot
    lo, hi = 10 * GAL_AC, 15 * GAL_AC   # 10-15 gal/ac in L/ha
    # A gal/ac map shows US units (`[output] units`); in metric its rates are L/ha.
    assert "the whole map: 10-15 gal/ac at 5.31-5.87 mph" in p.stdout, p.stdout
    p = vrsim("run", scen, "--check", "--set", "output.units=metric")
    assert f"the whole map: {lo:.0f}-{hi:.0f} L/ha at 2.38-2.62 m/s" in p.stdout, p.stdout


def test_tune_shows_the_rate_figures_in_the_maps_unit(tmp_path):
    scen = scenario(tmp_path, write_tif(tmp_path / "rx.tif", "lb/ac"))
    args = ("tune", scen, "--controller", "PI", "--param", "kp=0.05:2", "--param", "ki=0.1:10", "--objective",
            "mae_kg_ha", "--budget", "4", "--quiet")
    p = vrsim(*args, "--json", "--out", tmp_path / "a")
    assert p.returncode == 0, p.stderr
    tuned = json.loads(p.stdout)["tuned"]
    p = vrsim(*args, "--out", tmp_path / "b")
    assert p.returncode == 0, p.stderr
    line = next(row for row in p.stdout.splitlines() if row.strip().startswith("mae ["))
    assert line.split()[:3] == ["mae", "[lb/ac]", f"{tuned['in_rate_unit']['mae']:.4g}"], line
    assert "kg/ha" not in p.stdout
