"""Regenerate the small map fixtures in this folder with third-party writers (run from the repo root):

    .venv/bin/python tests/data/maps/make_fixtures.py

- rx_utm32.tif       GeoTIFF written by GDAL (rasterio): 4 x 5 cells of 10 m, EPSG:32632, nodata -1
- zones_utm32.zip    zipped shapefile written by pyshp: 3 rectangular zones (attribute RATE), with .prj
- zones_noprj.*      the same shapefile without .prj
- lines.*            a polyline shapefile (not rate zones) with .prj
"""

import os
import zipfile

import numpy as np
import pyproj
import rasterio
import shapefile
from affine import Affine

HERE = os.path.dirname(os.path.abspath(__file__))
X0, Y0 = 500_000.0, 5_300_050.0  # north-west corner, EPSG:32632 (zone 32N, near 47.8 N, 9 E)
PRJ = pyproj.CRS.from_epsg(32632).to_wkt(version="WKT1_ESRI")
# Three zones side by side, west to east: 0-20 m, 20-35 m, 35-50 m; 30 m north-south.
ZONES = [((0, 20), 100.0), ((20, 35), 150.0), ((35, 50), 200.0)]


def geotiff():
    rates = np.array([[100, 110, 120, 130, 140],
                      [150, 160, 170, 180, 190],
                      [200, 210, -1, 230, 240],
                      [250, 260, 270, 280, 290]], dtype=np.float32)
    with rasterio.open(os.path.join(HERE, "rx_utm32.tif"), "w", driver="GTiff", width=5, height=4,
                       count=1, dtype="float32", crs="EPSG:32632", transform=Affine(10, 0, X0, 0, -10, Y0),
                       nodata=-1) as d:
        d.write(rates, 1)


def zone_shapefile(stem, prj=True, lines=False):
    kind = shapefile.POLYLINE if lines else shapefile.POLYGON
    with shapefile.Writer(os.path.join(HERE, stem), shapeType=kind) as w:
        w.field("NAME", "C", size=10)
        w.field("RATE", "N", size=10, decimal=2)
        w.field("AREA_HA", "N", size=10, decimal=4)
        for i, ((a, b), rate) in enumerate(ZONES):
            ring = [(X0 + a, Y0), (X0 + b, Y0), (X0 + b, Y0 - 30), (X0 + a, Y0 - 30), (X0 + a, Y0)]
            if lines:
                w.line([ring])
            else:
                w.poly([ring])  # clockwise: a shapefile exterior ring
            w.record(f"zone{i}", rate, (b - a) * 30 / 10_000)
    if prj:
        with open(os.path.join(HERE, stem + ".prj"), "w") as f:
            f.write(PRJ)


def main():
    geotiff()
    zone_shapefile("zones_utm32")
    with zipfile.ZipFile(os.path.join(HERE, "zones_utm32.zip"), "w") as z:
        for ext in (".shp", ".shx", ".dbf", ".prj"):
            z.write(os.path.join(HERE, "zones_utm32" + ext), "zones_utm32" + ext)
            os.remove(os.path.join(HERE, "zones_utm32" + ext))
    zone_shapefile("zones_noprj", prj=False)
    zone_shapefile("lines", lines=True)


if __name__ == "__main__":
    main()
