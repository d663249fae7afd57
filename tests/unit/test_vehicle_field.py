import json
import os

import numpy as np
import pytest

from tests.conftest import ROOT
from vrsim.common.errors import VehicleError
from vrsim.vehicle import Field

DATA = os.path.join(ROOT, "tests", "data", "vehicle")


def test_rectangle_is_metric_utm():
    f = Field.rectangle(200.0, 300.0, lat=52.0, lon=10.0)
    assert f.area_ha == pytest.approx(6.0)
    assert f.crs.to_epsg() == 32632
    assert f.polygon.bounds[2] - f.polygon.bounds[0] == pytest.approx(200.0)


def test_wgs84_round_trip():
    f = Field.rectangle(100.0, 100.0, lat=-33.9, lon=18.4)
    assert f.crs.to_epsg() == 32734  # southern hemisphere zone 34
    x, y = np.array(f.polygon.exterior.coords).T
    lon, lat = f.to_wgs84(x, y)
    assert np.all(np.abs(lat + 33.9) < 0.01)
    x2, y2 = f.from_wgs84(lon, lat)
    assert np.allclose(x2, x, atol=1e-6) and np.allclose(y2, y, atol=1e-6)


def test_from_lonlat_l_shape_area():
    f = Field.from_file(os.path.join(DATA, "l_field.geojson"))
    g = Field.from_lonlat(json.load(open(os.path.join(DATA, "l_field.geojson")))
                          ["features"][0]["geometry"]["coordinates"][0])
    assert f.name == "l_field"
    assert f.area_ha == pytest.approx(g.area_ha)
    assert 6.0 < f.area_ha < 6.6  # 3 x 1.5 of 6.0 x 3.3 arc-second cells near 52 N


@pytest.mark.parametrize("name", ["u_field.shp", "u_field.zip"])
def test_shapefile_projected_with_prj(name):
    f = Field.from_file(os.path.join(DATA, name))
    assert f.crs.to_epsg() == 32632
    assert f.area_ha == pytest.approx(8.99, abs=0.01)


def test_projected_geojson_needs_crs(tmp_path):
    utm = Field.rectangle(50, 80)
    path = tmp_path / "utm.geojson"
    coords = [list(map(float, c)) for c in utm.polygon.exterior.coords]
    path.write_text(json.dumps({"type": "Polygon", "coordinates": [coords]}))
    with pytest.raises(VehicleError, match="no CRS given"):
        Field.from_file(str(path))
    f = Field.from_file(str(path), crs="EPSG:32632")
    assert f.area_ha == pytest.approx(0.4)


@pytest.mark.parametrize("name, match", [
    ("bowtie.geojson", "invalid: Self-intersection"),
    ("empty.geojson", "no Polygon"),
    ("missing.geojson", "not found"),
])
def test_bad_files_name_the_file(name, match):
    with pytest.raises(VehicleError, match=match) as err:
        Field.from_file(os.path.join(DATA, name))
    assert name in str(err.value)


@pytest.mark.parametrize("name", ["f.zip", "f.shp"])
def test_damaged_shapefile_is_a_vehicle_error(tmp_path, name):
    p = tmp_path / name
    p.write_text("garbage")
    with pytest.raises(VehicleError, match="not a readable shapefile|not a zip archive"):
        Field.from_file(str(p))


def test_bad_extension_and_bad_json(tmp_path):
    p = tmp_path / "f.gml"
    p.write_text("x")
    with pytest.raises(VehicleError, match="unknown extension"):
        Field.from_file(str(p))
    p = tmp_path / "f.kml"
    p.write_text("x")
    with pytest.raises(VehicleError, match="f.kml: not well-formed XML"):
        Field.from_file(str(p))
    p = tmp_path / "f.geojson"
    p.write_text("{not json")
    with pytest.raises(VehicleError, match="not readable GeoJSON"):
        Field.from_file(str(p))
    p.write_text('{"type": "FeatureCollection", "features": null}')
    with pytest.raises(VehicleError, match="no Polygon"):
        Field.from_file(str(p))
    p.write_text('{"type": "FeatureCollection", "crs": {"properties": "EPSG:4326"}, "features": [7]}')
    with pytest.raises(VehicleError, match="crs member"):
        Field.from_file(str(p))


@pytest.mark.parametrize("w, l", [(0, 10), (-5, 10), (10, float("nan"))])
def test_rectangle_rejects_bad_size(w, l):
    with pytest.raises(VehicleError, match="must be a number > 0 m, got"):
        Field.rectangle(w, l)


def test_degenerate_and_empty_boundaries(tmp_path):
    with pytest.raises(VehicleError, match="at least 3"):
        Field.from_lonlat([(10, 52), (10.1, 52)])
    with pytest.raises(VehicleError, match="invalid"):
        Field.from_lonlat([(10, 52), (10.1, 52), (10.2, 52)])
    p = tmp_path / "hollow.geojson"
    p.write_text('{"type": "Polygon", "coordinates": []}')
    with pytest.raises(VehicleError, match="hollow.geojson: boundary is empty"):
        Field.from_file(str(p))


def test_longest_edge_heading():
    assert Field.rectangle(100, 400).longest_edge_heading_deg() == pytest.approx(0.0, abs=1e-6)
    assert Field.rectangle(400, 100).longest_edge_heading_deg() == pytest.approx(90.0, abs=1e-6)


def test_fields_beyond_the_area_or_side_cap_are_refused_before_planning():
    with pytest.raises(VehicleError, match=r"'rectangle': boundary of 202,500 ha .* caps of 10,000 ha"):
        Field.rectangle(45_000.0, 45_000.0)
    with pytest.raises(VehicleError, match=r"rectangle: length_m = 1e\+09 m is over the cap of 50000 m"):
        Field.rectangle(12.0, 1e9)
    with pytest.raises(VehicleError, match=r"field 'wide': boundary of .* ha in a .* m x .* m box is over"):
        Field.from_lonlat([(10.0, 52.0), (11.0, 52.0), (11.0, 52.01), (10.0, 52.01)], name="wide")
    assert Field.rectangle(3_000.0, 3_000.0).area_ha == pytest.approx(900.0)
