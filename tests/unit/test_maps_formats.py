"""GeoTIFF, shapefile/GeoJSON zones and point tables: third-party files, round trips, bad input."""

import json
import os
import shutil
import warnings

import numpy as np
import pyogrio
import pytest
import rasterio
import shapefile
import shapely
from affine import Affine

from vrsim.common import MapError
from vrsim.maps import Grid, MapWarning, read_map, synthetic, write_map

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "maps")
X0, Y0 = 500_000.0, 5_300_050.0


def fixture(name):
    return os.path.join(DATA, name)


# ---------------------------------------------------------------------- GeoTIFF
def test_geotiff_written_by_gdal():
    g = read_map(fixture("rx_utm32.tif"), unit="kg/ha")
    assert g.crs.to_epsg() == 32632 and g.format == "geotiff"
    assert g.transform == Affine(10, 0, X0, 0, -10, Y0)
    assert g.rates_kg_ha[0, 0] == 100 and g.rates_kg_ha[3, 4] == 290
    assert np.isnan(g.rates_kg_ha[2, 2])  # the file's nodata (-1)
    assert g.rate_at(X0 + 45, Y0 - 35) == 290


TRANSFORM = Affine(10, 0, X0, 0, -10, Y0)


def write_tif(path, data, crs="EPSG:32632", transform=TRANSFORM, nodata=None):
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
                       dtype=data.dtype, crs=crs, transform=transform, nodata=nodata) as d:
        d.write(data, 1)


def test_geotiff_any_crs(tmp_path):
    # Web Mercator and a US State Plane CRS in feet: lookups in lon/lat land in the right cell.
    for crs in ("EPSG:3857", "EPSG:2227"):
        data = np.arange(12, dtype=np.float64).reshape(3, 4)
        write_tif(tmp_path / "a.tif", data, crs=crs, transform=Affine(100, 0, 1000, 0, -100, 5000))
        g = read_map(tmp_path / "a.tif", unit="kg/ha")
        lon, lat = _to_wgs84(1250.0, 4850.0, crs)
        assert g.lookup(lon, lat, crs="EPSG:4326").rate_kg_ha == 6.0


def _to_wgs84(x, y, crs):
    import pyproj

    return pyproj.Transformer.from_crs(crs, 4326, always_xy=True).transform(x, y)


@pytest.mark.parametrize("data,nodata,match", [
    (np.array([[1.0, -2.0]]), None, "negative rate"),
    (np.array([[1.0, np.nan]]), -9999.0, "NaN rates"),
])
def test_geotiff_bad_values(tmp_path, data, nodata, match):
    write_tif(tmp_path / "a.tif", data, nodata=nodata)
    with pytest.raises(MapError, match=match):
        read_map(tmp_path / "a.tif", unit="kg/ha")


def test_geotiff_nan_is_nodata_without_declared_value(tmp_path):
    write_tif(tmp_path / "a.tif", np.array([[1.0, np.nan]]))
    assert np.isnan(read_map(tmp_path / "a.tif", unit="kg/ha").rates_kg_ha[0, 1])


def test_geotiff_without_crs_needs_one(tmp_path):
    write_tif(tmp_path / "a.tif", np.ones((2, 2)), crs=None)
    with pytest.raises(MapError, match="no CRS"):
        read_map(tmp_path / "a.tif", unit="kg/ha")
    assert read_map(tmp_path / "a.tif", crs="EPSG:32633", unit="kg/ha").crs.to_epsg() == 32633


def test_geotiff_rotated_or_damaged_refused(tmp_path):
    write_tif(tmp_path / "r.tif", np.ones((2, 2)), transform=Affine(10, 2, X0, 2, -10, Y0))
    with pytest.raises(MapError, match="north-up"):
        read_map(tmp_path / "r.tif", unit="kg/ha")
    shutil.copy(fixture("rx_utm32.tif"), tmp_path / "t.tif")
    with open(tmp_path / "t.tif", "r+b") as f:
        f.truncate(100)
    with pytest.raises(MapError, match="t.tif"):
        read_map(tmp_path / "t.tif", unit="kg/ha")
    (tmp_path / "x.tif").write_text("not a tiff")
    with pytest.raises(MapError, match="cannot read as a raster"):
        read_map(tmp_path / "x.tif", unit="kg/ha")


def test_geotiff_cap(tmp_path):
    with pytest.raises(MapError, match="exceeds the cap"):
        read_map(fixture("rx_utm32.tif"), max_cells=10, unit="kg/ha")


@pytest.mark.parametrize("ext", [".tif", ".geojson", ".csv"])
def test_round_trip(tmp_path, ext):
    g = synthetic.random_field((X0, 5_299_900, X0 + 130, Y0), "EPSG:32632", cell_size_m=10, seed=5)
    g.rates_kg_ha[3, 4] = np.nan
    g.product = "CAN 27"
    write_map(g, tmp_path / f"out{ext}")
    back = read_map(tmp_path / f"out{ext}")
    np.testing.assert_array_equal(np.isnan(back.rates_kg_ha), np.isnan(g.rates_kg_ha))
    rtol = 6e-8 if ext == ".tif" else 1e-12  # GeoTIFFs are float32: 24-bit mantissa
    np.testing.assert_allclose(back.rates_kg_ha, g.rates_kg_ha, rtol=rtol, equal_nan=True)
    assert back.transform.almost_equals(g.transform, precision=1e-6)
    assert back.crs.to_epsg() == 32632
    if ext == ".tif":
        assert back.product == "CAN 27"


def test_geotiff_written_float32_with_description_unit_and_nodata(tmp_path):
    g = synthetic.uniform((0, 0, 20, 20), "EPSG:32632", cell_size_m=10, rate_kg_ha=1 / 3)
    g.rates_kg_ha[0, 1] = np.nan
    write_map(g, tmp_path / "a.tif")
    with rasterio.open(tmp_path / "a.tif") as src:
        assert src.dtypes == ("float32",) and src.nodata == -9999.0
        assert src.descriptions == ("application rate",) and src.units == ("kg/ha",)
        assert src.tags()["quantity"] == "rate" and src.read(1)[0, 1] == -9999.0
    back = read_map(tmp_path / "a.tif")
    assert back.rates_kg_ha[0, 0] == np.float32(1 / 3) and np.isnan(back.rates_kg_ha[0, 1])
    assert back.quantity == "rate"


def test_geotiff_signed_difference_read_but_negative_rates_refused(tmp_path):
    g = synthetic.uniform((0, 0, 20, 20), "EPSG:32632", cell_size_m=10, rate_kg_ha=5.0)
    g.rates_kg_ha[1, 1] = -12.5
    diff = Grid(g.rates_kg_ha, g.transform, g.crs, product="applied minus prescribed", quantity="difference")
    write_map(diff, tmp_path / "error.tif")
    back = read_map(tmp_path / "error.tif")
    assert back.quantity == "difference" and back.rates_kg_ha[1, 1] == -12.5
    assert back.info()["min_rate_kg_ha"] == -12.5 and back.info()["quantity"] == "difference"
    with rasterio.open(tmp_path / "error.tif") as src:
        assert src.descriptions == ("applied minus prescribed",)
    # Another tool's raster says so in its band description only.
    write_tif(tmp_path / "d.tif", diff.rates_kg_ha.astype(np.float32))
    with rasterio.open(tmp_path / "d.tif", "r+") as dst:
        dst.set_band_description(1, "Rate difference (kg/ha)")
    assert read_map(tmp_path / "d.tif", unit="kg/ha").quantity == "difference"
    # A rate map with a negative value is still refused.
    write_map(Grid(g.rates_kg_ha, g.transform, g.crs), tmp_path / "rx.tif")
    with pytest.raises(MapError, match="negative rate -12.5 kg/ha at row 1, column 1"):
        read_map(tmp_path / "rx.tif", unit="kg/ha")
    with pytest.raises(MapError, match="quantity must be one of"):
        Grid(g.rates_kg_ha, g.transform, g.crs, quantity="error")


def test_geojson_is_wgs84_without_crs_member(tmp_path):
    g = synthetic.random_field((X0, 5_299_900, X0 + 40, Y0), "EPSG:32632", cell_size_m=10, seed=2)
    write_map(g, tmp_path / "p.geojson")
    doc = json.loads((tmp_path / "p.geojson").read_text())
    assert "crs" not in doc and doc["grid_crs"] == "EPSG:32632"
    first = doc["features"][0]
    lon, lat = _to_wgs84(first["properties"]["x"], first["properties"]["y"], "EPSG:32632")
    assert first["geometry"]["coordinates"] == pytest.approx([lon, lat], abs=1e-9)
    info = pyogrio.read_info(str(tmp_path / "p.geojson"))  # GDAL, an RFC 7946 reader
    assert info["crs"] == "EPSG:4326" and info["features"] == g.rows * g.cols
    _, _, geometry, _ = pyogrio.raw.read(str(tmp_path / "p.geojson"))
    assert shapely.get_coordinates(shapely.from_wkb(geometry[:1]))[0] == pytest.approx([lon, lat], abs=1e-9)


# ---------------------------------------------------------------------- zones
def test_zipped_shapefile_area_weighted_edges():
    # Zones 100 | 150 | 200 with edges at 20 m and 35 m from the west; 10 m cells.
    g = read_map(fixture("zones_utm32.zip"), cell_size_m=10, unit="kg/ha")
    assert g.format == "shapefile" and g.crs.to_epsg() == 32632
    assert g.bounds == (X0, Y0 - 30, X0 + 50, Y0)
    np.testing.assert_allclose(g.rates_kg_ha[1], [100, 100, 150, 175, 200], atol=1e-9)


def test_shapefile_needs_crs_without_prj():
    with pytest.raises(MapError, match="no .prj"):
        read_map(fixture("zones_noprj.shp"), unit="kg/ha")
    g = read_map(fixture("zones_noprj.shp"), crs="EPSG:32632", cell_size_m=5, unit="kg/ha")
    assert g.rate_at(X0 + 1, Y0 - 1) == 100 and g.rate_at(X0 + 49, Y0 - 29) == 200


def test_shapefile_files_closed_after_reading(tmp_path):
    # The parts are read into memory and closed: no file is left for the garbage collector.
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", ResourceWarning)
        read_map(fixture("zones_noprj.shp"), crs="EPSG:32632", cell_size_m=5, unit="kg/ha")
        read_map(fixture("zones_utm32.zip"), cell_size_m=10, unit="kg/ha")
    assert not [w for w in seen if issubclass(w.category, ResourceWarning)]


def test_shapefile_non_polygon_refused():
    with pytest.raises(MapError, match="POLYLINE, not a polygon"):
        read_map(fixture("lines.shp"), unit="kg/ha")


def test_shapefile_missing_dbf_and_bad_field(tmp_path):
    for ext in (".shp", ".shx", ".prj"):
        shutil.copy(fixture("zones_noprj" + ext if ext != ".prj" else "lines.prj"), tmp_path / f"z{ext}")
    with pytest.raises(MapError, match=r"\.dbf .* is missing"):
        read_map(tmp_path / "z.shp", unit="kg/ha")
    shutil.copy(fixture("zones_noprj.dbf"), tmp_path / "z.dbf")
    with pytest.raises(MapError, match="no attribute 'N_RATE'"):
        read_map(tmp_path / "z.shp", rate_field="N_RATE", unit="kg/ha")
    with pytest.raises(MapError, match="NAME.* is not a number"):
        read_map(tmp_path / "z.shp", rate_field="NAME", unit="kg/ha")


def zones_geojson(path, features, crs=None):
    doc = {"type": "FeatureCollection", "features": features}
    if crs:
        doc["crs"] = {"type": "name", "properties": {"name": crs}}
    path.write_text(json.dumps(doc))
    return path


def square(x, y, size):
    ring = [[x, y], [x + size, y], [x + size, y + size], [x, y + size], [x, y]]
    return {"type": "Polygon", "coordinates": [ring]}


def test_geojson_zones_wgs84_rasterized_in_utm(tmp_path):
    feats = [{"type": "Feature", "geometry": square(9.0 + 0.001 * i, 48.0, 0.001),
              "properties": {"Rate": rate, "Id": i}} for i, rate in enumerate((120, 180))]
    g = read_map(zones_geojson(tmp_path / "z.geojson", feats), cell_size_m=2, unit="kg/ha")
    assert g.crs.to_epsg() == 32632 and g.cell_size == (2.0, 2.0) and g.format == "geojson"
    assert g.lookup(9.0005, 48.0005, crs="EPSG:4326").rate_kg_ha == 120
    assert g.lookup(9.0015, 48.0005, crs="EPSG:4326").rate_kg_ha == 180
    # Cells straddling the (curved in UTM) zone edge are area-weighted blends; none leaves the range.
    rates = g.rates_kg_ha[~np.isnan(g.rates_kg_ha)]
    assert rates.min() == 120 and rates.max() == 180
    assert ((rates > 120) & (rates < 180)).sum() >= g.rows - 2


@pytest.mark.parametrize("props,kwargs,match", [
    ([{"a": 1, "b": 2}], {}, "cannot tell which attribute is the rate"),
    ([{"rate": -3}], {}, "must be finite and not negative"),
    ([{"rate": None}], {}, "is not a number"),
    ([{"rate": "NaN"}], {}, "must be finite"),
])
def test_geojson_zone_attribute_errors(tmp_path, props, kwargs, match):
    feats = [{"type": "Feature", "geometry": square(X0, Y0, 10), "properties": p} for p in props]
    with pytest.raises(MapError, match=match):
        read_map(zones_geojson(tmp_path / "z.geojson", feats, "EPSG:32632"), **kwargs, unit="kg/ha")


def test_geojson_single_numeric_attribute_is_used_with_warning(tmp_path):
    feats = [{"type": "Feature", "geometry": square(X0, Y0, 10), "properties": {"name": "a", "N_kg": 90}}]
    with pytest.warns(MapWarning, match="N_kg"):
        g = read_map(zones_geojson(tmp_path / "z.geojson", feats, "EPSG:32632"), unit="kg/ha")
    assert np.nanmax(g.rates_kg_ha) == 90


def test_geojson_bad_input(tmp_path):
    (tmp_path / "a.geojson").write_text("{not json")
    with pytest.raises(MapError, match="not valid JSON"):
        read_map(tmp_path / "a.geojson", unit="kg/ha")
    (tmp_path / "b.geojson").write_text('{"type": "Topology"}')
    with pytest.raises(MapError, match="not a GeoJSON FeatureCollection"):
        read_map(tmp_path / "b.geojson", unit="kg/ha")
    line = {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}
    feats = [{"type": "Feature", "geometry": line, "properties": {"rate": 1}}]
    with pytest.raises(MapError, match="LineString, not a polygon"):
        read_map(zones_geojson(tmp_path / "c.geojson", feats), unit="kg/ha")
    (tmp_path / "d.geojson").write_text('{"type": "FeatureCollection"}')
    with pytest.raises(MapError, match="'features' is not a list"):
        read_map(tmp_path / "d.geojson", unit="kg/ha")


def test_geojson_points_skip_features_without_geometry(tmp_path):
    # A null-geometry feature places no point; its rate must not shift the others' onto wrong cells.
    def point(x, rate):
        return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [x, 52.0]},
                "properties": {"rate": rate}}

    empty = {"type": "Feature", "geometry": None, "properties": {"rate": 5}}
    doc = {"type": "FeatureCollection", "features": [empty, point(10.0, 100), point(10.001, 120)]}
    (tmp_path / "p.geojson").write_text(json.dumps(doc))
    g = read_map(tmp_path / "p.geojson", unit="kg/ha")
    assert (g.rows, g.cols) == (1, 2)
    assert g.rates_kg_ha.tolist() == [[100.0, 120.0]]


def test_many_small_zones_rasterize_each_into_its_own_cell(tmp_path):
    # 20,000 polygons of 5 m x 5 m (a 100 x 200 mosaic), written by pyshp, rasterized at 5 m. (How long
    # 50,000 take: `bench/bench_maps.py`, ``zones_50k_rasterize_s``.)
    path = str(tmp_path / "many")
    with shapefile.Writer(path, shapeType=shapefile.POLYGON) as w:
        w.field("RATE", "N", size=8, decimal=1)
        for i in range(20_000):
            r, c = divmod(i, 200)
            x, y = X0 + 5 * c, Y0 - 5 * r
            w.poly([[(x, y), (x + 5, y), (x + 5, y - 5), (x, y - 5), (x, y)]])
            w.record(float(i % 300))
    with open(path + ".prj", "w") as f:
        with open(fixture("lines.prj")) as src:
            f.write(src.read())
    g = read_map(path + ".shp", cell_size_m=5, unit="kg/ha")
    assert (g.rows, g.cols) == (100, 200)
    np.testing.assert_array_equal(g.rates_kg_ha.ravel(), np.arange(20_000) % 300)


# ---------------------------------------------------------------------- points, dispatch
def test_foreign_csv_lonlat_points(tmp_path):
    # A point table from other software: lon/lat on a regular 0.001 deg lattice, no row/col columns.
    lines = ["longitude,latitude,Rate"] + [f"{9 + 0.001 * c:.3f},{48 + 0.001 * r:.3f},{10 * r + c}"
                                            for r in range(3) for c in range(4)]
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    g = read_map(tmp_path / "p.csv", unit="kg/ha")
    assert (g.rows, g.cols) == (3, 4) and g.crs.to_epsg() == 4326
    assert g.sample(lat=48.002, lon=9.003)["rate_kg_ha"] == 23
    assert g.sample(lat=48.0, lon=9.0)["rate_kg_ha"] == 0


def test_csv_errors(tmp_path):
    (tmp_path / "a.csv").write_text("x,y,rate\n1,2,3\n")
    with pytest.raises(MapError, match="no .prj"):
        read_map(tmp_path / "a.csv", unit="kg/ha")
    (tmp_path / "a.prj").write_bytes(b"\xff\xfe not a CRS")
    with pytest.raises(MapError, match="a.prj"):
        read_map(tmp_path / "a.csv", unit="kg/ha")
    (tmp_path / "a.prj").unlink()
    (tmp_path / "b.csv").write_text("foo,bar\n1,2\n")
    with pytest.raises(MapError, match="needs x,y or lon,lat"):
        read_map(tmp_path / "b.csv", unit="kg/ha")
    (tmp_path / "c.csv").write_text("lon,lat,rate\n9,48,abc\n")
    with pytest.raises(MapError, match="is not a number"):
        read_map(tmp_path / "c.csv", unit="kg/ha")
    (tmp_path / "d.csv").write_text("lon,lat,rate\n9,48,1\n9.001,48,-1\n")
    with pytest.raises(MapError, match="negative rate"):
        read_map(tmp_path / "d.csv", unit="kg/ha")
    (tmp_path / "e.csv").write_text("lon,lat,rate\n9,48,1\n9.001,48,1\n9.0025,48,1\n")
    with pytest.raises(MapError, match="not the cell centres of a regular"):
        read_map(tmp_path / "e.csv", unit="kg/ha")


def test_dispatch_errors(tmp_path):
    with pytest.raises(MapError, match="no such file"):
        read_map(tmp_path / "nope.tif")
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(MapError, match="unknown map format"):
        read_map(tmp_path / "a.txt")
    g = Grid(np.ones((2, 2)), Affine(1, 0, 0, 0, -1, 0), "EPSG:32632")
    with pytest.raises(MapError, match="unknown output format"):
        write_map(g, tmp_path / "a.txt")
    with pytest.raises(MapError, match="does not exist"):
        write_map(g, tmp_path / "no" / "a.tif")


def test_isoxml_zip_nodata_warns(tmp_path):
    g = Grid(np.array([[1.0, np.nan]]), Affine(0.001, 0, 9, 0, -0.001, 48), "EPSG:4326")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        write_map(g, tmp_path / "t.zip")
    assert any("no nodata value" in str(w.message) for w in caught)
    np.testing.assert_array_equal(read_map(tmp_path / "t.zip", unit="kg/ha").rates_kg_ha, [[1.0, 0.0]])


def test_geojson_multipolygon_with_hole(tmp_path):
    def box(w, n, size):
        x, y = X0 + w, Y0 - n
        return [[x, y], [x + size, y], [x + size, y - size], [x, y - size], [x, y]]

    outer, hole, far = box(0, 0, 40), box(10, 10, 20), box(60, 0, 10)
    geom = {"type": "MultiPolygon", "coordinates": [[outer, hole], [far]]}
    feats = [{"type": "Feature", "geometry": geom, "properties": {"rate_kg_ha": 80}}]
    g = read_map(zones_geojson(tmp_path / "z.geojson", feats, "EPSG:32632"), cell_size_m=10, unit="kg/ha")
    assert (g.rows, g.cols) == (4, 7)
    assert np.isnan(g.rates_kg_ha[1:3, 1:3]).all() and np.isnan(g.rates_kg_ha[:, 4:6]).all()
    assert g.rates_kg_ha[0, 0] == 80 and g.rates_kg_ha[0, 6] == 80
    assert np.count_nonzero(~np.isnan(g.rates_kg_ha)) == 12 + 1


def test_damaged_shapefile_refused(tmp_path):
    for ext in (".shp", ".shx", ".dbf", ".prj"):
        shutil.copy(fixture("lines" + ext if ext == ".prj" else "zones_noprj" + ext), tmp_path / f"z{ext}")
    data = (tmp_path / "z.shp").read_bytes()
    (tmp_path / "z.shp").write_bytes(data[:150])  # cut inside the first record
    with pytest.raises(MapError, match="damaged .shp"):
        read_map(tmp_path / "z.shp", unit="kg/ha")
    (tmp_path / "z.shp").write_bytes(b"\0" * 120)
    with pytest.raises(MapError, match="bad header"):
        read_map(tmp_path / "z.shp", unit="kg/ha")
