"""Farm files with several layers or products, through the real executable: a zip or folder of
several shapefiles is listed and read by `--layer`, a TASKDATA grid of two products by `--product`;
nothing is chosen silently and a name that does not exist exits 2 with one line listing what exists."""

import json
import os
import re
import subprocess
import zipfile

import numpy as np
import pytest
from affine import Affine

from tests.conftest import VRSIM
from vrsim.maps import Grid, read_map, write_map

DEERE = os.path.join("data", "asapplied", "jd-gen4-application-point-onehertz.zip")
LAYERS = ("Tank Mix Rate-Tank Mix", "Seeding-Corn", "Harvest-Yield", "Application-Product2")


def vrsim(*args):
    return subprocess.run([VRSIM, *map(str, args)], capture_output=True, text=True, timeout=120)


def one_line_exit_2(p, *needles):
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    for needle in needles:
        assert needle in p.stderr, (needle, p.stderr)


@pytest.fixture()
def four_layers(shared_dir, tmp_path):
    """An Operations Center style zip of four point layers (the Deere export under four names), the
    third with every target doubled."""
    source = zipfile.ZipFile(os.path.join(shared_dir, DEERE))
    path = tmp_path / "four.zip"
    with zipfile.ZipFile(path, "w") as z:
        for layer in LAYERS:
            for name in source.namelist():
                z.writestr(name.replace("--------Tank Mix Rate-Tank Mix", layer), source.read(name))
    return path


def test_a_zip_of_four_layers_is_listed_and_read_by_layer(four_layers, tmp_path):
    p = vrsim("evaluate", four_layers)
    listed = (f"'{x}' (780 records; fields Time" for x in LAYERS)
    one_line_exit_2(p, "four.zip", "4 layers", "--layer", *listed)
    p = vrsim("evaluate", four_layers, "--layer", "Harvest-Yield", "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert got["points"] == 780 and got["unit"] == "gal/ac"  # its own Deere metadata gives the unit
    one_line_exit_2(vrsim("evaluate", four_layers, "--layer", "Nope"), "no layer 'Nope'", "'Seeding-Corn'")
    folder = tmp_path / "export"
    folder.mkdir()
    zipfile.ZipFile(four_layers).extractall(folder)
    one_line_exit_2(vrsim("evaluate", folder), "4 layers")
    p = vrsim("evaluate", folder, "--layer", "seeding-corn", "--json")
    assert p.returncode == 0 and json.loads(p.stdout) == got, p.stderr


def test_a_zip_of_two_zone_layers_is_read_by_layer(tmp_path):
    """`vrsim map` on a zip of two rate-zone shapefiles: listed without --layer, each read by name."""
    import pyogrio
    import shapely

    square = shapely.box(500_000, 5_800_000, 500_100, 5_800_100)
    path = tmp_path / "zones.zip"
    with zipfile.ZipFile(path, "w") as z:
        for name, rate in (("north", 120.0), ("south", 80.0)):
            shp = tmp_path / f"{name}.shp"
            pyogrio.raw.write(str(shp), shapely.to_wkb(np.array([square])), [np.array([rate])],
                              ["Rate_kg_ha"],
                              driver="ESRI Shapefile", geometry_type="Polygon", crs="EPSG:32632")
            for ext in (".shp", ".shx", ".dbf", ".prj"):
                z.write(tmp_path / f"{name}{ext}", f"{name}{ext}")
    one_line_exit_2(vrsim("map", "info", path), "2 layers", "'north' (1 records; fields Rate_kg_ha)",
                    "'south'")
    p = vrsim("map", "info", path, "--layer", "south", "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["max_rate_kg_ha"] == 80.0
    one_line_exit_2(vrsim("map", "info", path, "--layer", "east"), "no layer 'east'", "'north'")


def two_products(tmp_path):
    """A TASKDATA grid (type 2) with DDI 6 of two products: PDT1 'Urea' 100 kg/ha, PDT2 'KAS' 250."""
    grid = Grid(np.full((3, 4), 100.0), Affine(1e-4, 0, 10.0, 0, -1e-4, 52.0), "EPSG:4326", product="Urea")
    folder = tmp_path / "TASKDATA"
    write_map(grid, folder)
    xml = (folder / "TASKDATA.XML").read_text()
    first = '<PDV A="0006" B="0" E="VPN1" C="PDT1" />'
    xml = xml.replace(first, first + '\n      <PDV A="0006" B="0" E="VPN1" C="PDT2" />')
    xml = xml.replace('<PDT A="PDT1" B="Urea" />', '<PDT A="PDT1" B="Urea" />\n  <PDT A="PDT2" B="KAS" />')
    assert xml.count("PDT2") == 2, xml
    cells = np.stack([np.full(12, 10_000), np.full(12, 25_000)], axis=1).astype("<i4")
    xml = re.sub(r'H="\d+"', f'H="{cells.nbytes}"', xml)
    (folder / "TASKDATA.XML").write_text(xml)
    (folder / "GRD00001.BIN").write_bytes(cells.tobytes())
    return folder


def test_a_taskdata_of_two_products_is_listed_and_read_by_product(tmp_path):
    folder = two_products(tmp_path)
    one_line_exit_2(vrsim("map", "info", folder), "2 products", "PDT1 'Urea'", "PDT2 'KAS'", "--product")
    for choice, rate, name in (("PDT2", 250.0, "KAS"), ("kas", 250.0, "KAS"), ("Urea", 100.0, "Urea")):
        p = vrsim("map", "info", folder, "--product", choice, "--json")
        assert p.returncode == 0, p.stderr
        info = json.loads(p.stdout)
        assert info["max_rate_kg_ha"] == rate and info["product"] == name, info
    p = vrsim("map", "info", folder, "--rate-field", "PDT2", "--json")  # --rate-field names it too
    assert p.returncode == 0 and json.loads(p.stdout)["product"] == "KAS", p.stderr
    one_line_exit_2(vrsim("map", "info", folder, "--product", "PDT3"), "no product 'PDT3'", "PDT1 'Urea'")
    assert read_map(folder, product="PDT1").product == "Urea"


def test_convert_writes_a_zipped_shapefile_prescription_read_back_by_vrsim_and_pyogrio(tmp_path):
    """Three zones (one with a hole of nodata) on 10 m cells: one polygon per zone, the rate attribute
    named with its unit, a .prj; vrsim reads the same rates back on the same cells, nodata kept."""
    import pyogrio
    import shapely

    rates = np.full((6, 8), 120.0)
    rates[:, 5:] = 80.555
    rates[2:4, 1:3] = np.nan  # a hole in the 120 zone: no polygon, so the terminal applies nothing
    rates[5, 0] = 150.0
    transform = Affine(10, 0, 500_000, 0, -10, 5_800_060)
    write_map(Grid(rates, transform, "EPSG:32632"), tmp_path / "rx.tif")
    p = vrsim("map", "convert", tmp_path / "rx.tif", tmp_path / "rx.shp.zip")
    assert p.returncode == 0, p.stderr
    assert sorted(zipfile.ZipFile(tmp_path / "rx.shp.zip").namelist()) == [
        "rx.cpg", "rx.dbf", "rx.prj", "rx.shp", "rx.shx"]
    meta, _, geometry, (values,) = pyogrio.raw.read(f"/vsizip/{tmp_path / 'rx.shp.zip'}/rx.shp")
    assert list(meta["fields"]) == ["Rate_kg_ha"] and pyogrio.read_info(
        f"/vsizip/{tmp_path / 'rx.shp.zip'}/rx.shp")["crs"] == "EPSG:32632"
    polygons = shapely.from_wkb(geometry)
    assert sorted(values.tolist()) == [80.56, 120.0, 150.0]  # one polygon per zone, 0.01 kg/ha
    by_rate = dict(zip(values.tolist(), polygons, strict=True))
    assert len(by_rate[120.0].interiors) == 1 and by_rate[120.0].area == pytest.approx((30 - 4 - 1) * 100)
    back = read_map(tmp_path / "rx.shp.zip", cell_size_m=10.0)
    assert back.unit == "kg/ha" and back.rates_kg_ha.shape == rates.shape
    np.testing.assert_allclose(back.rates_kg_ha, np.round(rates, 2), equal_nan=True)
    error = Grid(rates - 100.0, transform, "EPSG:32632", quantity="difference")
    write_map(error, tmp_path / "error.tif")
    one_line_exit_2(vrsim("map", "convert", tmp_path / "error.tif", tmp_path / "e.shp.zip"),
                    "e.shp.zip", "differences")


def test_evaluate_field_from_kml_with_a_hole_and_bad_kml(shared_dir, tmp_path):
    """`--field` a KML around every point of the Deere export with a hole over its southern half: about
    half the points are compared; a KML with no polygon exits 2 naming the file."""
    from vrsim import maps

    path = os.path.join(shared_dir, DEERE)
    log = maps.read_point_log(path)
    west, east = log.x.min() - 0.001, log.x.max() + 0.001
    south, north = log.y.min() - 0.001, log.y.max() + 0.001
    mid = float(np.median(log.y))

    def coords(w, s, e, n):
        return " ".join(f"{x},{y}" for x, y in ((w, s), (e, s), (e, n), (w, n), (w, s)))

    kml = tmp_path / "field.kml"
    kml.write_text('<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><Polygon><outerBoundaryIs>'
                   f"<LinearRing><coordinates>{coords(west, south, east, north)}</coordinates>"
                   "</LinearRing></outerBoundaryIs>"
                   "<innerBoundaryIs><LinearRing><coordinates>"
                   f"{coords(west + 1e-4, south + 1e-4, east - 1e-4, mid)}</coordinates></LinearRing>"
                   "</innerBoundaryIs></Polygon></Placemark></kml>")
    p = vrsim("evaluate", path, "--field", kml, "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert 300 < got["points"] < 480 and got["excluded"]["outside_field"] == 780 - got["points"]
    kml.write_text("<kml><Placemark><Point><coordinates>10,52</coordinates></Point></Placemark></kml>")
    one_line_exit_2(vrsim("evaluate", path, "--field", kml), "field.kml", "no Polygon")


def test_evaluate_against_a_two_product_prescription_takes_product(tmp_path):
    import pyogrio
    import shapely

    folder = two_products(tmp_path)
    n = 20
    lon, lat = 10.00005 + np.linspace(0, 3e-4, n), np.full(n, 51.99985)
    log = tmp_path / "log.gpkg"
    pyogrio.raw.write(str(log), shapely.to_wkb(shapely.points(lon, lat)),
                      [np.full(n, 250.0), np.full(n, 250.0), np.full(n, "kg/ha", dtype=object)],
                      ["applied", "target", "rate_unit"], driver="GPKG", geometry_type="Point",
                      crs="EPSG:4326")
    one_line_exit_2(vrsim("evaluate", log, "--prescription", folder), "2 products", "PDT2 'KAS'")
    p = vrsim("evaluate", log, "--prescription", folder, "--product", "KAS", "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert got["points"] == n and got["mae"] == 0.0
