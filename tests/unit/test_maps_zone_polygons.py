"""A zone file's polygons read without GDAL (`read_zone_table(..., attributes=False)`, a field from a
prescription): the polygons and CRS GDAL reads, and no GDAL loaded."""

import os
import subprocess
import sys

import pytest
import shapely

from vrsim.common import MapError
from vrsim.maps.zone_table import read_zone_table

DATA = os.path.join(os.path.dirname(__file__), os.pardir, "data", "maps")


def _multipolygons_with_holes(folder) -> str:
    """A shapefile of two zones: a square with a hole, and two squares as one record (multipolygon);
    outer rings clockwise, holes counter-clockwise, as the format has them."""
    import shapefile

    def square(x, y, size, clockwise=True):
        ring = [(x, y), (x, y + size), (x + size, y + size), (x + size, y), (x, y)]
        return ring if clockwise else ring[::-1]

    path = os.path.join(folder, "zones_holes.shp")
    with shapefile.Writer(path, shapeType=shapefile.POLYGON) as w:
        w.field("rate", "N", decimal=0)
        w.poly([square(500000, 5500000, 100), square(500040, 5500040, 20, clockwise=False)])
        w.record(120)
        w.poly([square(500200, 5500000, 50), square(500300, 5500000, 50)])
        w.record(80)
    return path


@pytest.mark.parametrize(("path", "layer", "crs"), [
    ("zones_utm32.zip", None, None),
    ("zones_noprj.shp", None, "EPSG:32632"),
    (".", "zones_noprj", "EPSG:32632"),      # a folder of several: the layer named
    ("holes", None, "EPSG:32632"),           # multipolygons, holes (written by the test)
])
def test_the_polygons_without_gdal_are_gdals(path, layer, crs, tmp_path):
    path = _multipolygons_with_holes(tmp_path) if path == "holes" else os.path.join(DATA, path)
    gdal = read_zone_table(path, layer=layer, crs=crs)
    ours = read_zone_table(path, layer=layer, crs=crs, attributes=False)
    assert [shapely.to_wkb(g) for g in ours.polygons] == [shapely.to_wkb(g) for g in gdal.polygons]
    assert ours.crs == gdal.crs and ours.layer == gdal.layer and ours.attributes == {}


def test_lines_are_refused_and_several_layers_asked_for_without_gdal():
    with pytest.raises(MapError, match="not a polygon"):
        read_zone_table(os.path.join(DATA, "lines.shp"), attributes=False)
    with pytest.raises(MapError, match="holds 2 layers"):
        read_zone_table(DATA, crs="EPSG:32632", attributes=False)


def test_reading_the_polygons_loads_no_gdal():
    code = ("import sys; from vrsim.maps.zone_table import read_zone_table; "
            f"read_zone_table({os.path.join(DATA, 'zones_utm32.zip')!r}, attributes=False); "
            "print('pyogrio' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
