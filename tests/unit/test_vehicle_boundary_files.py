"""Field boundaries from KML/KMZ and the ISOXML partfield, and holes from every format: read with their
holes, which the coverage path and the field's cells leave out; bad boundaries refused in one line
naming the file and the value."""

import json
import os
import zipfile

import numpy as np
import pytest
import shapely

from vrsim.common.errors import VehicleError
from vrsim.vehicle import Field
from vrsim.vehicle.coverage import plan_coverage

# A 300 m x 200 m field at 52 N 10 E (about 0.0044 x 0.0018 degrees) with a 60 m x 40 m hole in it.
WEST, SOUTH, EAST, NORTH = 10.0, 52.0, 10.0044, 52.0018
HOLE = (10.0018, 52.0007, 10.0026, 52.0011)


def ring(west, south, east, north, close=True):
    xy = [(west, south), (east, south), (east, north), (west, north)]
    return xy + [xy[0]] * close


def kml(outer, inner=(), ns=True):
    def coords(xy):
        return " ".join(f"{x},{y},0" for x, y in xy)

    holes = "".join(f"<innerBoundaryIs><LinearRing><coordinates>{coords(r)}</coordinates></LinearRing>"
                    "</innerBoundaryIs>" for r in inner)
    xmlns = ' xmlns="http://www.opengis.net/kml/2.2"' if ns else ""
    return (f'<?xml version="1.0" encoding="UTF-8"?><kml{xmlns}>'
            "<Document><Placemark><name>North field</name><Polygon><outerBoundaryIs><LinearRing>"
            f"<coordinates>{coords(outer)}</coordinates></LinearRing></outerBoundaryIs>{holes}</Polygon>"
            "</Placemark></Document></kml>")


def partfield_xml(pfds):
    """A TASKDATA.XML with partfields [(id, designator, [rings]: exterior first, then interiors)]."""
    out = ['<?xml version="1.0" encoding="UTF-8"?><ISO11783_TaskData VersionMajor="4" VersionMinor="3" '
           'DataTransferOrigin="1">']
    for pid, name, rings in pfds:
        out.append(f'<PFD A="{pid}" C="{name}" D="60000"><PLN A="1">')
        for i, r in enumerate(rings):
            points = "".join(f'<PNT A="2" C="{y}" D="{x}"/>' for x, y in r[:-1])  # left open, as allowed
            out.append(f'<LSG A="{1 if i == 0 else 2}">{points}</LSG>')
        out.append("</PLN></PFD>")
    return "".join(out + ["</ISO11783_TaskData>"])


def assert_holed(field: Field):
    """The hole is kept: area, cells inside it not in the field, no swath or headland pass through it."""
    outer = Field.from_lonlat(ring(WEST, SOUTH, EAST, NORTH))
    hole = Field.from_lonlat(ring(*HOLE))
    assert len(field.polygon.interiors) == 1
    assert field.area_ha == pytest.approx(outer.area_ha - hole.area_ha, rel=1e-6)
    x, y = field.from_wgs84((HOLE[0] + HOLE[2]) / 2, (HOLE[1] + HOLE[3]) / 2)
    assert not shapely.contains_xy(field.polygon, x, y)  # the field's cells (metrics) leave it out
    obstacle = shapely.Polygon(field.polygon.interiors[0]).buffer(-0.01)
    path = plan_coverage(field, 6.0, headland_passes=1, turn_radius_m=4.0)
    assert not any(shapely.LineString(s.xy).intersects(obstacle) for s in path.segments if s.kind != "turn")


def test_kml_and_kmz_with_a_hole(tmp_path):
    path = tmp_path / "north.kml"
    path.write_text(kml(ring(WEST, SOUTH, EAST, NORTH), [ring(*HOLE)[::-1]]))
    field = Field.from_file(str(path))
    assert field.name == "north"
    assert_holed(field)
    kmz = tmp_path / "north.kmz"
    with zipfile.ZipFile(kmz, "w") as z:
        z.writestr("doc.kml", kml(ring(WEST, SOUTH, EAST, NORTH), [ring(*HOLE)], ns=False))
    assert_holed(Field.from_file(str(kmz)))


def test_isoxml_partfield_with_a_hole(tmp_path, shared_dir):
    folder = tmp_path / "TASKDATA"
    folder.mkdir()
    (folder / "TASKDATA.XML").write_text(partfield_xml([("PFD1", "North", [ring(WEST, SOUTH, EAST, NORTH),
                                                                           ring(*HOLE)])]))
    for given in (folder, folder / "TASKDATA.XML"):
        assert_holed(Field.from_file(str(given)))
    two = tmp_path / "two.zip"
    with zipfile.ZipFile(two, "w") as z:
        z.writestr("TASKDATA/TASKDATA.XML", partfield_xml([
            ("PFD1", "North", [ring(WEST, SOUTH, EAST, NORTH), ring(*HOLE)]),
            ("PFD2", "South", [ring(WEST, SOUTH - 0.01, EAST, NORTH - 0.01)])]))
    with pytest.raises(VehicleError, match=r"two.zip: 2 partfields have a boundary: PFD1 'North', PFD2"):
        Field.from_file(str(two))
    assert_holed(Field.from_file(str(two), partfield="North"))
    assert len(Field.from_file(str(two), partfield="PFD2").polygon.interiors) == 0
    with pytest.raises(VehicleError, match="no partfield 'PFD9'.*PFD1 'North'"):
        Field.from_file(str(two), partfield="PFD9")
    xfarm = Field.from_file(os.path.join(shared_dir, "data", "isoxml", "isoxml-js-task_with_grid.zip"))
    assert xfarm.area_ha > 0


def test_geojson_and_shapefile_with_a_hole(tmp_path):
    import pyogrio

    polygon = shapely.Polygon(ring(WEST, SOUTH, EAST, NORTH), [ring(*HOLE)])
    path = tmp_path / "f.geojson"
    path.write_text(json.dumps({"type": "Feature", "properties": {},
                                "geometry": shapely.geometry.mapping(polygon)}))
    assert_holed(Field.from_file(str(path)))
    shp = tmp_path / "f.shp"
    pyogrio.raw.write(str(shp), shapely.to_wkb(np.array([polygon])), [np.array([1])], ["id"],
                      driver="ESRI Shapefile", geometry_type="Polygon", crs="EPSG:4326")
    assert_holed(Field.from_file(str(shp)))


@pytest.mark.parametrize("text, needles", [
    ('<kml><Placemark><Point><coordinates>10,52</coordinates></Point></Placemark></kml>', ["no Polygon"]),
    (kml(ring(WEST, SOUTH, EAST, NORTH, close=False)), ["does not close", "(10.0, 52.0)", "52.0018)"]),
    (kml([(WEST, SOUTH), (EAST, NORTH), (EAST, SOUTH), (WEST, NORTH), (WEST, SOUTH)]),
     ["invalid", "Self-intersection"]),
    (kml([(WEST, SOUTH), ("ten", SOUTH), (EAST, NORTH), (WEST, SOUTH)]), ["coordinate 'ten,52.0,0'"]),
    ('<!DOCTYPE kml [<!ENTITY a "aaaa">]><kml>&a;</kml>', ["refused"]),
])
def test_bad_kml_names_file_and_value(tmp_path, text, needles):
    path = tmp_path / "bad.kml"
    path.write_text(text)
    with pytest.raises(VehicleError) as caught:
        Field.from_file(str(path))
    message = str(caught.value)
    assert "bad.kml" in message and "\n" not in message
    for needle in needles:
        assert needle in message, message


def test_geojson_ring_that_does_not_close(tmp_path):
    path = tmp_path / "open.geojson"
    open_ring = ring(WEST, SOUTH, EAST, NORTH, close=False)
    path.write_text(json.dumps({"type": "Polygon", "coordinates": [open_ring]}))
    with pytest.raises(VehicleError, match=r"open.geojson: a ring does not close: it starts at \(10.0, 52.0\)"
                       ):
        Field.from_file(str(path))


def test_kml_with_several_placemarks_is_not_read_by_a_guess(tmp_path):
    one = kml(ring(WEST, SOUTH, EAST, NORTH), [ring(*HOLE)])
    mark = one[one.index("<Placemark>"):one.index("</Placemark>") + len("</Placemark>")]
    other = mark.replace("North field", "South field")
    path = tmp_path / "two.kml"
    path.write_text(one.replace(mark, mark + other))
    with pytest.raises(VehicleError, match="two.kml: 2 placemarks have polygons: 'North field', 'South"):
        Field.from_file(str(path))
    assert_holed(Field.from_file(str(path), partfield="South field"))
    with pytest.raises(VehicleError, match="no placemark 'East' with a polygon; placemarks: 'North field'"):
        Field.from_file(str(path), partfield="East")
