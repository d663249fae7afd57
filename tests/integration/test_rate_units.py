"""Rate units end to end, through the real executable and real SUMO runs: a lb/ac GeoTIFF and a gal/ac
shapefile prescription run and every output states its unit; a map that states none is refused in one
line saying how to give it; `--set map.unit=...` gives it; a unit pint cannot read, or of the wrong
kind, exits 2 naming file, key and value."""

import json
import os
import subprocess

import numpy as np
import pytest
import rasterio
import shapefile
from affine import Affine

from tests.conftest import VRSIM
from vrsim.maps import read_map, read_point_log, read_taskdata_log
from vrsim.maps.units import convert_rate

LB_AC = float(convert_rate(1.0, "lb/ac", "kg/ha"))  # kg/ha in one lb/ac
GAL_AC = float(convert_rate(1.0, "gal/ac", "L/ha"))  # L/ha in one gal/ac
WEST, SOUTH, STEP = 11.5995, 48.1995, 0.0001  # the maps cover the field (SW corner 11.6 E, 48.2 N)
SCENARIO = """name = "{name}"
seed = 3
[field]
rectangle = {{ width_m = 60.0, length_m = 100.0, lat = 48.2, lon = 11.6 }}
headland_passes = 1
[map]
file = "{map}"
{map_keys}
[implement]
width_m = 12.0
delivery_delay_s = 0.8
[output]
plots = false
html = true
{extra}
"""


def vrsim(*args, cwd=None):
    return subprocess.run([VRSIM, *map(str, args)], capture_output=True, text=True, timeout=300, cwd=cwd)


def one_line_exit_2(p, *needles):
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    for needle in needles:
        assert needle in p.stderr, (needle, p.stderr)


def zone_rates(rows: int, cols: int, low: float, high: float) -> np.ndarray:
    """West half `low`, east half `high`."""
    rates = np.full((rows, cols), low)
    rates[:, cols // 2:] = high
    return rates


def write_tif(path, unit: str | None, low=100.0, high=150.0):
    rates = zone_rates(20, 20, low, high).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=20, height=20, count=1, dtype="float32",
                       crs="EPSG:4326", transform=Affine(STEP, 0, WEST, 0, -STEP, SOUTH + 20 * STEP)) as dst:
        dst.write(rates, 1)
        if unit is not None:
            dst.units = (unit,)
    return path


def write_gal_ac_shapefile(stem, low=10.0, high=15.0):
    """Two zone polygons (west, east) with attribute R_gal_ac, WGS84 with a .prj (pyshp)."""
    east, north, mid = WEST + 20 * STEP, SOUTH + 20 * STEP, WEST + 10 * STEP
    with shapefile.Writer(str(stem), shapeType=shapefile.POLYGON) as w:
        w.field("R_gal_ac", "N", 8, 2)  # a DBF name holds 10 characters
        for (a, b), rate in (((WEST, mid), low), ((mid, east), high)):
            w.poly([[(a, SOUTH), (a, north), (b, north), (b, SOUTH), (a, SOUTH)]])
            w.record(rate)
    with open(f"{stem}.prj", "w") as fh:
        fh.write('GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],'
                 'PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]]')
    return f"{stem}.shp"


def scenario(tmp_path, map_file, map_keys="", extra="", name="units"):
    path = tmp_path / f"{name}.toml"
    path.write_text(SCENARIO.format(name=name, map=os.path.basename(map_file), map_keys=map_keys,
                                    extra=extra))
    return path


def band_unit(path) -> str:
    with rasterio.open(path) as src:
        return src.units[0]


def test_lb_ac_geotiff_runs_end_to_end_and_every_output_states_lb_ac(tmp_path):
    scen = scenario(tmp_path, write_tif(tmp_path / "rx.tif", "lb/ac"))
    out = tmp_path / "out"
    p = vrsim("run", scen, "--json", "--quiet", "--out", out)
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["rate_unit"] == "lb/ac"
    # The run computes in kg/ha (its *_kg_ha keys); the map's unit is one conversion away.
    for key in ("mae", "rmse", "bias"):
        assert s["in_rate_unit"][key] == pytest.approx(s[f"{key}_kg_ha"] / LB_AC, rel=1e-12)
    assert 0 < s["mae_kg_ha"] < 0.2 * 150 * LB_AC and abs(s["mass_balance_pct"]) < 5
    assert json.loads((out / "summary.json").read_text())["rate_unit"] == "lb/ac"
    # Files: the rasters in lb/ac (band unit), the prescription as the file gave it.
    for name in ("prescription.tif", "as_applied.tif", "error.tif"):
        assert band_unit(out / name) == "lb/ac", name
    rx = read_map(out / "prescription.tif")
    assert rx.map_unit == "lb/ac"
    assert np.nanmax(rx.in_map_unit(rx.rates_kg_ha)) == pytest.approx(150, rel=1e-6)
    assert np.nanmax(rx.rates_kg_ha) == pytest.approx(150 * LB_AC, rel=1e-6)
    applied = read_map(out / "as_applied.tif")
    assert np.nanmedian(applied.in_map_unit(applied.rates_kg_ha)) == pytest.approx(125, rel=0.25)
    # The TimeLog: mass per area (DDI 7) read back in kg/ha; the points file states lb/ac.
    log = read_taskdata_log(out / "taskdata")
    assert log.unit == "kg/ha" and np.nanmax(log.target) == pytest.approx(150 * LB_AC, rel=1e-3)
    points = read_point_log(out / "as_applied_points.gpkg")
    assert points.unit == "lb/ac" and np.nanmax(points.target) == pytest.approx(150, rel=1e-3)
    html = (out / "report.html").read_text()
    mae = f"{s['in_rate_unit']['mae']:,.2f}"
    assert f"Mean absolute error</td><td class=n>{mae}</td><td>lb/ac</td>" in html
    assert "mean absolute error (lb/ac)" in html and "GeoTIFF, lb/ac" in html
    # The text summary shows the rate figures in lb/ac.
    p = vrsim("run", scen, "--quiet", "--out", tmp_path / "out2")
    assert p.returncode == 0, p.stderr
    line = next(row for row in p.stdout.splitlines() if "Mean absolute error" in row)
    assert line.endswith("lb/ac") and f"{s['in_rate_unit']['mae']:,.2f}" in line


def test_map_info_and_sample_in_the_maps_unit(tmp_path):
    tif = write_tif(tmp_path / "rx.tif", "lbs/ac")
    p = vrsim("map", "info", tif)
    assert p.returncode == 0, p.stderr
    assert "max_rate         150 lb/ac" in p.stdout and "kg_ha" not in p.stdout
    info = json.loads(vrsim("map", "info", tif, "--json").stdout)
    assert info["rate_unit"] == "lb/ac" and info["max_rate"] == pytest.approx(150)
    assert info["max_rate_kg_ha"] == pytest.approx(150 * LB_AC)
    p = vrsim("map", "sample", tif, "--lat", SOUTH + 0.001, "--lon", WEST + 0.0019, "--json")
    got = json.loads(p.stdout)
    assert got["rate"] == pytest.approx(150) and got["rate_unit"] == "lb/ac"
    assert got["rate_kg_ha"] == pytest.approx(150 * LB_AC)
    p = vrsim("map", "sample", tif, "--lat", SOUTH + 0.001, "--lon", WEST + 0.0001)
    assert p.stdout.startswith("100 lb/ac"), p.stdout


def test_a_map_without_a_unit_is_refused_in_one_line_and_set_gives_it(tmp_path):
    tif = write_tif(tmp_path / "rx.tif", None)
    scen = scenario(tmp_path, tif)
    p = vrsim("run", scen, "--quiet", "--out", tmp_path / "out")
    one_line_exit_2(p, f"{scen}: [map]", "does not state the unit of its rates", '[map] unit = "lb/ac"',
                    "--unit")
    p = vrsim("map", "info", tif)   # describes first: the values as stored, and what to give
    assert p.returncode == 0 and "not stated in the file" in p.stdout and "give --unit" in p.stdout, p
    p = vrsim("map", "info", tif, "--unit", "lb/ac", "--json")
    assert p.returncode == 0 and json.loads(p.stdout)["rate_unit"] == "lb/ac", p.stderr
    p = vrsim("run", scen, "--json", "--quiet", "--out", tmp_path / "out", "--set", "map.unit=lb/ac")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["rate_unit"] == "lb/ac"


@pytest.mark.parametrize("unit, needle", [("widgets/ac", "is not a unit pint reads"),
                                          ("kg", "is not a rate (mass, volume or count per area")])
def test_a_bad_unit_exits_2_naming_file_key_and_value(tmp_path, unit, needle):
    scen = scenario(tmp_path, write_tif(tmp_path / "rx.tif", None), map_keys=f'unit = "{unit}"')
    one_line_exit_2(vrsim("run", scen, "--quiet", "--out", tmp_path / "out"),
                    f"{scen}: [map] unit: {unit!r}", needle)
    # A file stating a unit pint cannot read: map info describes it and names the band unit, its value
    # and why it does not read.
    tif = write_tif(tmp_path / "bad.tif", unit)
    p = vrsim("map", "info", tif)
    assert p.returncode == 0 and f"band unit: {unit!r}" in p.stdout and needle in p.stdout, p
    assert json.loads(vrsim("map", "info", tif, "--json").stdout)["unit_problem"].startswith("band unit")
    # A unit given that the file contradicts.
    one_line_exit_2(vrsim("map", "info", write_tif(tmp_path / "kg.tif", "kg/ha"), "--unit", "lb/ac"),
                    "states its rates in kg/ha (band unit), not in the unit given, 'lb/ac'")


def test_a_gal_ac_shapefile_is_read_and_needs_a_density_to_run_as_mass(tmp_path):
    shp = write_gal_ac_shapefile(tmp_path / "rx")
    grid = read_map(shp, cell_size_m=2)  # no density: held in gal/ac, no prescription
    assert grid.unit == grid.map_unit == "gal/ac" and np.nanmax(grid.rates_kg_ha) == pytest.approx(15)
    dense = read_map(shp, cell_size_m=2, density_kg_l=1.2)
    assert dense.unit == "kg/ha" and dense.map_unit == "gal/ac"
    assert np.nanmax(dense.rates_kg_ha) == pytest.approx(15 * GAL_AC * 1.2)
    # Without [product] density_kg_l the run refuses: no guessed density.
    one_line_exit_2(vrsim("run", scenario(tmp_path, shp), "--quiet", "--out", tmp_path / "out"),
                        "a volume rate (gal/ac) runs as a mass rate only with the product's density",
                        "[product] density_kg_l")


def test_gal_ac_shapefile_runs_end_to_end_and_every_output_states_gal_ac(tmp_path):
    scen = scenario(tmp_path, write_gal_ac_shapefile(tmp_path / "rx"), extra="[product]\ndensity_kg_l = 1.2")
    out = tmp_path / "out"
    p = vrsim("run", scen, "--json", "--quiet", "--out", out)
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["rate_unit"] == "gal/ac"
    assert s["in_rate_unit"]["mae"] == pytest.approx(s["mae_kg_ha"] / (GAL_AC * 1.2), rel=1e-12)
    for name in ("prescription.tif", "as_applied.tif", "error.tif"):
        assert band_unit(out / name) == "gal/ac", name
    log = read_taskdata_log(out / "taskdata")  # volume per area: DDI 2, read in L/ha
    assert log.unit == "L/ha" and np.nanmax(log.target) == pytest.approx(15 * GAL_AC, rel=1e-3)
    assert "gal/ac" in (out / "report.html").read_text()


DEERE = os.path.join("data", "asapplied", "jd-gen4-application-point-onehertz.zip")


def write_constant_tif(path, log, rate: float, unit: str):
    """A one-rate GeoTIFF in `unit` over the points of `log` (WGS84) with a margin."""
    west, south = log.x.min() - 0.001, log.y.min() - 0.001
    cols, rows = int((log.x.max() + 0.001 - west) / STEP) + 1, int((log.y.max() + 0.001 - south) / STEP) + 1
    transform = Affine(STEP, 0, west, 0, -STEP, south + rows * STEP)
    with rasterio.open(path, "w", driver="GTiff", width=cols, height=rows, count=1, dtype="float32",
                       crs="EPSG:4326", transform=transform) as dst:
        dst.write(np.full((rows, cols), rate, np.float32), 1)
        dst.units = (unit,)
    return path


def test_evaluate_a_gal_ac_log_against_l_ha_gal_ac_and_kg_ha_maps(shared_dir, tmp_path):
    """The real John Deere export (gal/ac, its Deere metadata says so) against maps in three units: in
    the map's unit each time, the same comparison; a mass rate map needs the product's density."""
    path = os.path.join(shared_dir, DEERE)
    log = read_point_log(path)
    assert log.unit == "gal/ac" and log.points == 780  # the data README's known values

    def evaluate(rx, *extra):
        p = vrsim("evaluate", path, "--prescription", rx, "--json", *extra)
        assert p.returncode == 0, p.stderr
        return json.loads(p.stdout)

    in_gal = evaluate(write_constant_tif(tmp_path / "gal.tif", log, 10.0, "gal/ac"))
    in_l = evaluate(write_constant_tif(tmp_path / "l.tif", log, 10.0 * GAL_AC, "L/ha"))
    assert in_gal["unit"] == "gal/ac" and in_l["unit"] == "L/ha"
    assert in_gal["applied_mean"] == pytest.approx(10.009, abs=0.001)
    assert in_l["applied_mean"] == pytest.approx(in_gal["applied_mean"] * GAL_AC, rel=1e-6)
    assert in_l["mae"] == pytest.approx(in_gal["mae"] * GAL_AC, rel=1e-4)
    kg = write_constant_tif(tmp_path / "kg.tif", log, 10.0 * GAL_AC * 1.1, "kg/ha")
    one_line_exit_2(vrsim("evaluate", path, "--prescription", kg),
                    "(kg/ha)", "cannot convert a volume rate (gal/ac) to a mass rate (kg/ha)",
                    "--density-kg-l")
    in_kg = evaluate(kg, "--density-kg-l", "1.1")
    assert in_kg["unit"] == "kg/ha"
    assert in_kg["applied_mean"] == pytest.approx(in_gal["applied_mean"] * GAL_AC * 1.1, rel=1e-6)
    assert in_kg["mae"] == pytest.approx(in_gal["mae"] * GAL_AC * 1.1, rel=1e-4)
