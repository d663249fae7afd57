"""`vrsim map` through the real executable: info, sample, convert, plot, and bad input (exit 2)."""

import json
import os
import subprocess

import numpy as np
import pytest

from tests.conftest import VRSIM
from vrsim.maps import read_map

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "maps")
TIF = os.path.join(DATA, "rx_utm32.tif")  # written by GDAL without a unit: given with --unit
KG_HA = ("--unit", "kg/ha")


def vrsim(*args):
    return subprocess.run([VRSIM, "map", *map(str, args)], capture_output=True, text=True, timeout=120)


def isoxml(shared_dir, name):
    return os.path.join(shared_dir, "data", "isoxml", name)


def test_info_json():
    p = vrsim("info", TIF, *KG_HA, "--json")
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    assert info["format"] == "geotiff" and info["crs"] == "EPSG:32632"
    assert info["rows"] == 4 and info["cols"] == 5 and info["cell_size"] == [10.0, 10.0]
    assert info["bounds"] == [500000.0, 5300010.0, 500050.0, 5300050.0]
    west, south, east, north = info["bounds_wgs84"]
    assert 8.99 < west < east < 9.01 and 47.8 < south < north < 47.9
    assert info["min_rate_kg_ha"] == 100 and info["max_rate_kg_ha"] == 290
    assert info["nodata_share"] == pytest.approx(0.05)


def test_info_text():
    p = vrsim("info", TIF, *KG_HA)
    assert p.returncode == 0 and "EPSG:32632" in p.stdout and "nodata_share" in p.stdout
    assert "max_rate         290 kg/ha" in p.stdout


def test_info_without_a_unit_shows_the_values_as_stored():
    p = vrsim("info", TIF)
    assert p.returncode == 0, p.stderr
    assert "not stated in the file" in p.stdout and "--unit" in p.stdout
    assert "max_rate         290\n" in p.stdout and "rate_unit        not stated" in p.stdout
    info = json.loads(vrsim("info", TIF, "--json").stdout)
    assert info["rate_unit"] is None and info["max_rate"] == 290 and "max_rate_kg_ha" not in info


def test_sample_isoxml_lat_lon_and_outside(shared_dir):
    t2 = isoxml(shared_dir, "isoxml-dotnet-Type2/TASKDATA.XML")
    lat = 55.82481700900832 + 3.5 * 0.0000902618210782717
    lon = 39.138728173503324 + 4.5 * 0.00016294086058760767
    p = vrsim("sample", t2, "--lat", lat, "--lon", lon, "--json")
    assert p.returncode == 0
    assert json.loads(p.stdout) == {"rate_kg_ha": 16997.91, "rate": 16997.91, "rate_unit": "kg/ha",
                                    "inside": True, "row": 6, "col": 4}
    assert p.stderr.count("\n") == 1 and "warning: " in p.stderr and "Filelength" in p.stderr
    p = vrsim("sample", t2, "--lat", 10, "--lon", 10, "--json")
    assert p.returncode == 0
    assert json.loads(p.stdout) == {"rate_kg_ha": None, "rate": None, "rate_unit": "kg/ha", "inside": False,
                                    "row": None, "col": None}
    p = vrsim("sample", t2, "--lat", 10, "--lon", 10)
    assert p.returncode == 0 and "outside" in p.stdout


def test_sample_x_y():
    p = vrsim("sample", TIF, *KG_HA, "--x", 500_045, "--y", 5_300_015, "--json")
    assert json.loads(p.stdout) == {"rate_kg_ha": 290.0, "rate": 290.0, "rate_unit": "kg/ha", "inside": True,
                                    "row": 3, "col": 4}
    p = vrsim("sample", TIF, *KG_HA, "--x", 500_025, "--y", 5_300_025)
    assert p.returncode == 0 and "nodata" in p.stdout


@pytest.mark.parametrize("out", ["rx.tif", "TASKDATA.XML", "rx.zip", "rx.geojson", "rx.csv"])
def test_convert_round_trip_through_cli(tmp_path, shared_dir, out):
    src = isoxml(shared_dir, "isoxml-js-task_with_grid.zip")
    p = vrsim("convert", src, tmp_path / out)
    assert p.returncode == 0, p.stderr
    before, after = read_map(src), read_map(tmp_path / out)  # in-process: one CLI start per case
    assert after.crs == before.crs and after.transform.almost_equals(before.transform, precision=1e-9)
    np.testing.assert_allclose(after.rates_kg_ha, before.rates_kg_ha, rtol=1e-7)


def test_convert_reprojecting(tmp_path, shared_dir):
    src = isoxml(shared_dir, "isoxml-js-task_with_grid.zip")
    p = vrsim("convert", src, tmp_path / "utm.tif", "--to-crs", "EPSG:32632", "--to-cell-size", 2)
    assert p.returncode == 0, p.stderr
    info = json.loads(vrsim("info", tmp_path / "utm.tif", "--json").stdout)
    assert info["crs"] == "EPSG:32632" and info["cell_size"] == [2.0, 2.0]
    # The xFarm map is continuous (190 rates), so the 2 m cells interpolate bilinearly between the
    # ~10 m cell centres: the UTM cell holding the xFarm cell (20, 30) centre has the source map's
    # bilinear value at its own centre (vrsim's Grid.lookup, independent of GDAL; GDAL's transformer
    # places centres within a few hundredths of a cell of pyproj's), near the cell's 3002.2.
    lat = 56.42601949235737 + 20.5 * 0.00009028027270540372
    lon = 9.925274835877255 + 30.5 * 0.00016434866866111552
    got = json.loads(vrsim("sample", tmp_path / "utm.tif", "--lat", lat, "--lon", lon, "--json").stdout)
    utm = read_map(tmp_path / "utm.tif")
    cx, cy = (c[i] for c, i in zip(utm.cell_centres(), (got["col"], got["row"]), strict=True))
    expected = read_map(src).lookup(cx, cy, crs="EPSG:32632", bilinear=True).rate_kg_ha
    assert got["rate_kg_ha"] == pytest.approx(float(expected), rel=1e-4)
    assert got["rate_kg_ha"] == pytest.approx(3002.2, rel=0.005)


def test_plot(tmp_path, shared_dir):
    p = vrsim("plot", isoxml(shared_dir, "isoxml-js-task_with_grid.zip"), tmp_path / "m.png")
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_zones_options(tmp_path):
    p = vrsim("info", os.path.join(DATA, "zones_noprj.shp"), "--crs", "EPSG:32632", "--cell-size", 10,
              "--rate-field", "RATE", *KG_HA, "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["mean_rate_kg_ha"] == pytest.approx((100 * 20 + 150 * 15 + 200 * 15) / 50)


def bad(*args):
    p = vrsim(*args)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stdout + p.stderr
    assert p.stderr.strip() and len(p.stderr.strip().splitlines()) == 1, p.stderr
    return p.stderr


def test_bad_input_exit_2_one_line(tmp_path, shared_dir):
    assert "32 bytes" in bad("info", isoxml(shared_dir, "isoxml-dotnet-Type1_Invalid/TASKDATA.XML"))
    assert "is missing" in bad("info", isoxml(shared_dir, "isoxml-js-grid-without-binary.zip"))
    assert "no such file" in bad("info", tmp_path / "nope.tif")
    assert "exceeds the cap" in bad("info", TIF, "--max-cells", 10)
    assert "does not state the unit of its rates" in bad("sample", TIF, "--x", 500_001, "--y", 5_300_049)
    assert "no .prj" in bad("info", os.path.join(DATA, "zones_noprj.shp"), *KG_HA)
    assert "not a polygon" in bad("info", os.path.join(DATA, "lines.shp"))
    assert "give --lat and --lon" in bad("sample", TIF)
    assert "give --lat and --lon" in bad("sample", TIF, "--lat", 1, "--x", 2)
    assert "finite" in bad("sample", TIF, "--lat", "nan", "--lon", 1)
    assert "unknown output format" in bad("convert", TIF, *KG_HA, tmp_path / "a.txt")
    assert "needs --to-crs" in bad("convert", tmp_path / "nope.tif", tmp_path / "a.tif", "--to-cell-size", 2)
    assert ".png" in bad("plot", TIF, *KG_HA, "--out", tmp_path / "a.jpg")
    hostile = '<!DOCTYPE x [<!ENTITY a "b">]><ISO11783_TaskData>&a;</ISO11783_TaskData>'
    (tmp_path / "TASKDATA.XML").write_text(hostile)
    assert "refused" in bad("info", tmp_path / "TASKDATA.XML")
