"""A field from the prescription (issue 38): a many-polygon zone shapefile made for it (a hole, a ring
that crosses itself, no unit stated) is the field of a run (`[field] from_map = true`), `vrsim map
boundary` writes that field, a `[field] file` of many polygons is refused unless its union is asked
for, and `vrsim map info` describes the file before any unit is given. Real files, the real executable."""

import json
import subprocess

import numpy as np
import pyproj
import pytest
import shapely

from tests.conftest import VRSIM
from vrsim.maps.zone_rx import write_zone_rx

SCENARIO = """name = "rx"
[field]
{field}
[map]
file = "rx.zip"
unit = "lb/ac"
cell_size_m = 2.0
[implement]
width_m = 12.0
sections = 4
[output]
plots = false
html = false
track = "none"
"""


def vrsim(*args, timeout=300):
    return subprocess.run([VRSIM, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def rx(tmp_path_factory):
    """A 4 ha zone shapefile of ~150 cells with a pond (a hole) and a bow-tie ring; (path, facts)."""
    folder = tmp_path_factory.mktemp("rx")
    facts = write_zone_rx(str(folder / "rx.zip"), area_ha=4.0, zones=150, seed=7, pond_ha=0.1,
                          invalid_ring=True)
    return folder / "rx.zip", facts


def union_ha(path) -> tuple[float, int]:
    """The zones' union in their UTM zone, made valid first, its parts and holes under 100 m^2 (the
    default sliver area) left out, computed here apart from vrsim: (ha, holes)."""
    import pyogrio

    _, _, wkb, _ = pyogrio.raw.read(f"/vsizip/{path}/rx.shp")
    to = pyproj.Transformer.from_crs(4326, 32632, always_xy=True)
    utm = shapely.transform(shapely.from_wkb(wkb),
                            lambda xy: np.column_stack(to.transform(xy[:, 0], xy[:, 1])))
    parts = [p for p in shapely.get_parts(shapely.union_all(shapely.make_valid(utm))) if p.area >= 100.0]
    assert len(parts) == 1
    holes = [shapely.Polygon(r).area for r in parts[0].interiors if shapely.Polygon(r).area >= 100.0]
    return (shapely.Polygon(parts[0].exterior).area - sum(holes)) / 1e4, len(holes)


def scenario(folder, field_lines: str):
    path = folder / "s.toml"
    path.write_text(SCENARIO.format(field=field_lines))
    return path


def test_the_run_takes_its_field_from_the_zones_union(rx, tmp_path):
    path, facts = rx
    area_ha, holes = union_ha(path)
    assert facts["zones"] > 100 and holes == 1
    p = vrsim("run", scenario(path.parent, "from_map = true"), "--json", "--quiet", "--out", tmp_path / "out")
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["field_area_ha"] == pytest.approx(area_ha, rel=1e-3)
    warned = [line for line in p.stderr.splitlines() if "make_valid" in line]
    assert len(warned) == 1 and warned[0].startswith("vrsim run: warning: ")
    assert "Self-intersection" in warned[0]


def test_a_field_file_of_many_polygons_is_refused_unless_its_union_is_asked_for(rx, tmp_path):
    path, _ = rx
    p = vrsim("run", scenario(path.parent, 'file = "rx.zip"'), "--check")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    line = p.stderr.strip()
    assert len(line.splitlines()) == 1 and "holds 1" in line and "polygons" in line
    assert "union = true" in line and "from_map = true" in line
    p = vrsim("run", scenario(path.parent, 'file = "rx.zip"\nunion = true'), "--check", "--json")
    assert p.returncode in (0, 3), p.stderr
    checked = vrsim("run", scenario(path.parent, "from_map = true"), "--check", "--json")
    assert json.loads(p.stdout) == json.loads(checked.stdout)


@pytest.mark.parametrize("field, message", [
    ("from_map = true\nfile = \"rx.zip\"", "exactly one of file, rectangle, polygon_lonlat, from_map"),
    ("rectangle = { width_m = 50.0, length_m = 50.0, lat = 50.0, lon = 9.0 }\nunion = true",
     "union = true is for a file"),
    ("from_map = true\nsliver_m2 = -1", "sliver_m2 must be a number >= 0"),
])
def test_bad_field_keys_exit_2_in_one_line(rx, field, message):
    path, _ = rx
    p = vrsim("run", scenario(path.parent, field), "--check")
    assert p.returncode == 2 and message in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_map_boundary_writes_the_union_whole(rx, tmp_path):
    path, _ = rx
    area_ha, holes = union_ha(path)
    out = tmp_path / "field.geojson"
    p = vrsim("map", "boundary", path, out)
    assert p.returncode == 0, p.stderr
    assert "make_valid" in p.stderr and "1 hole," in p.stdout
    doc = json.loads(out.read_text())
    (feature,) = doc["features"]
    polygon = shapely.geometry.shape(feature["geometry"])
    assert polygon.geom_type == "Polygon" and len(polygon.interiors) == holes and polygon.is_valid
    assert feature["properties"]["area_ha"] == pytest.approx(area_ha, rel=1e-3)
    # read back as a field file: the same field
    back = vrsim("run", scenario(path.parent, f'file = "{out}"'), "--check", "--json")
    checked = vrsim("run", scenario(path.parent, "from_map = true"), "--check", "--json")
    assert back.returncode == checked.returncode and json.loads(back.stdout) == json.loads(checked.stdout)


def test_map_boundary_bad_input_exit_2_nothing_written(rx, tmp_path):
    path, _ = rx
    point = {"type": "Feature", "properties": {"rate": 1},
             "geometry": {"type": "Point", "coordinates": [9, 50]}}
    (tmp_path / "points.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [point]}))
    (tmp_path / "none.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    for args, message in [((path, tmp_path / "a.txt"), "must end in .geojson"),
                          ((tmp_path / "nope.zip", tmp_path / "a.geojson"), "no such file"),
                          ((tmp_path / "points.geojson", tmp_path / "a.geojson"), "not a polygon"),
                          ((tmp_path / "none.geojson", tmp_path / "a.geojson"), "no polygon"),
                          ((path, tmp_path / "a.geojson", "--sliver-m2", 1e9), "separate parts"),
                          ((path, tmp_path / "b.geojson", "--out", tmp_path / "a.geojson"), "once")]:
        p = vrsim("map", "boundary", *args)
        assert p.returncode == 2 and message in p.stderr and "Traceback" not in p.stderr, (args, p.stderr)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["none.geojson", "points.geojson"]


def test_map_info_describes_a_unitless_zone_file_before_any_unit(rx):
    path, facts = rx
    p = vrsim("map", "info", path)
    assert p.returncode == 0, p.stderr
    out = p.stdout
    assert f"{facts['zones']:,} polygons" in out and "EPSG:4326" in out
    assert "rate           real (whole numbers)" in out and "2 distinct: 0, 10" in out
    assert "Id             integer" in out and f"1 .. {facts['zones']}" in out
    assert "rate_attribute   rate (its name is one farm software gives the rate" in out
    assert "not stated in the file: give --unit" in out and "min_rate" not in out
    info = json.loads(vrsim("map", "info", path, "--json").stdout)
    assert info["attributes"]["rate"]["values"] == [0.0, 10.0] and info["stated_unit"] is None
    assert info["zones"] == facts["zones"] and info["rate_attribute"] == "rate"
    assert info["zones_area_ha"] == pytest.approx(facts["area_ha"], rel=0.02)
    p = vrsim("map", "info", path, "--unit", "lb/ac")
    assert p.returncode == 0 and "rates read from  attribute 'rate' in lb/ac" in p.stdout
    assert "max_rate         10 lb/ac" in p.stdout and "lb/ac (given with --unit" in p.stdout
    info = json.loads(vrsim("map", "info", path, "--unit", "lb/ac", "--json").stdout)
    assert info["rate_attribute_used"] == "rate" and info["max_rate"] == 10.0 and info["rate_unit"] == "lb/ac"


def test_map_plot_takes_out_and_the_older_positional_with_a_note(rx, tmp_path):
    path, _ = rx
    p = vrsim("map", "plot", path, "--unit", "lb/ac", "--out", tmp_path / "a.png")
    assert p.returncode == 0 and p.stderr == "" and (tmp_path / "a.png").read_bytes()[:4] == b"\x89PNG"
    p = vrsim("map", "plot", path, tmp_path / "b.png", "--unit", "lb/ac")
    assert p.returncode == 0 and "older form" in p.stderr and "--out" in p.stderr
    assert (tmp_path / "b.png").exists()
    p = vrsim("map", "plot", path, "--unit", "lb/ac")
    assert p.returncode == 2 and "--out" in p.stderr
