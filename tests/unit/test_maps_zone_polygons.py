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
NATURAL_EARTH = os.path.join(os.path.dirname(shapely.__file__), os.pardir, "pyogrio", "tests", "fixtures",
                             "naturalearth_lowres", "naturalearth_lowres.shp")


@pytest.mark.parametrize(("path", "layer", "crs"), [
    ("zones_utm32.zip", None, None),
    ("zones_noprj.shp", None, "EPSG:32632"),
    (".", "zones_noprj", "EPSG:32632"),      # a folder of several: the layer named
    (NATURAL_EARTH, None, None),              # multipolygons, holes
])
def test_the_polygons_without_gdal_are_gdals(path, layer, crs):
    path = os.path.join(DATA, path)
    if not os.path.exists(path):
        pytest.skip("no such fixture")
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
    code = ("import sys; from maps.zone_table import read_zone_table; "
            f"read_zone_table({os.path.join(DATA, 'zones_utm32.zip')!r}, attributes=False); "
            "print('pyogrio' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
