"""Writes the map files some library scenarios read (checked in; rerun only to change them):

- ``isoxml_zones/TASKDATA.XML`` + ``GRD00001.BIN``: zones as an ISO 11783-10 grid type 2 (WGS84),
  written by vrsim's ISOXML writer, as a farm-management program would send to a terminal;
- ``zones_shapefile.zip``: rate-zone polygons (attribute ``RATE``, kg/ha, WGS84 with .prj) written by
  pyshp and zipped, as such exports usually arrive;
- ``stripes_along_travel.geojson``: 30 m-wide zones whose edges run north-south, along the swaths of a
  field worked at heading 0 (attribute ``RATE``, kg/ha, WGS84), for the per-section drives.
- ``zones_lb_ac.tif``: zones in lb/ac (US units, the band's unit says so), written by rasterio in
  WGS84 as a US farm program exports a prescription.
- ``zones_l_ha.tif``: zones in L/ha (a sprayer's prescription, the band's unit says so), 140-220 L/ha,
  written the same way.

All cover the library's 120 m x 250 m rectangle at 52.0 N, 10.0 E with a margin.

    .venv/bin/python tests/accuracy/scenarios/maps/make_maps.py
"""

import json
import os
import zipfile

import numpy as np
import pyproj
import shapefile
import shapely

from vrsim.maps import synthetic, utm_crs_for, write_map

HERE = os.path.dirname(os.path.abspath(__file__))
LON, LAT = 10.0, 52.0
MARGIN_M = 40.0


def field_bounds_utm():
    crs = utm_crs_for(LON, LAT)
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(LON, LAT)
    return crs, (x0 - MARGIN_M, y0 - MARGIN_M, x0 + 120 + MARGIN_M, y0 + 250 + MARGIN_M)


def write_isoxml():
    crs, bounds = field_bounds_utm()
    zones = synthetic.zones(bounds=bounds, crs=crs, cell_size_m=2.0, seed=5, n_zones=5,
                            rate_range_kg_ha=(110.0, 240.0), rate_step_kg_ha=10.0)
    wgs = zones.reproject("EPSG:4326", cell_size_m=4.0)
    out = os.path.join(HERE, "isoxml_zones")
    os.makedirs(out, exist_ok=True)
    write_map(wgs, os.path.join(out, "TASKDATA.XML"))


def write_shapefile():
    crs, (minx, miny, maxx, maxy) = field_bounds_utm()
    rng = np.random.default_rng(7)
    seeds = shapely.MultiPoint(rng.uniform((minx, miny), (maxx, maxy), size=(6, 2)))
    box = shapely.box(minx, miny, maxx, maxy)
    cells = [c.intersection(box) for c in shapely.voronoi_polygons(seeds, extend_to=box).geoms]
    to_wgs = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    base = os.path.join(HERE, "zones_shapefile")
    with shapefile.Writer(base, shapeType=shapefile.POLYGON) as w:
        w.field("ZONE", "N", 4, 0)
        w.field("RATE", "N", 8, 1)
        for i, cell in enumerate(cells):
            # Shapefile outer rings run clockwise.
            cw = shapely.geometry.polygon.orient(cell, sign=-1.0)
            lon, lat = to_wgs.transform(*np.asarray(cw.exterior.coords).T)
            ring = list(zip(lon.tolist(), lat.tolist(), strict=True))
            w.poly([ring])
            w.record(i + 1, float(100 + 30 * (i % 5)))
    with open(base + ".prj", "w") as fh:
        fh.write(pyproj.CRS("EPSG:4326").to_wkt("WKT1_ESRI"))
    with zipfile.ZipFile(base + ".zip", "w", zipfile.ZIP_DEFLATED) as z:
        for ext in (".shp", ".shx", ".dbf", ".prj"):
            z.write(base + ext, "zones_shapefile" + ext)
            os.remove(base + ext)


STRIPE_M = 30.0
STRIPE_RATES_KG_HA = (120.0, 220.0, 160.0, 250.0)


def write_stripes():
    crs, (minx, miny, maxx, maxy) = field_bounds_utm()
    to_wgs = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    features = []
    for i, x0 in enumerate(np.arange(minx, maxx, STRIPE_M)):
        lon, lat = to_wgs.transform(*np.asarray(shapely.box(x0, miny, min(x0 + STRIPE_M, maxx), maxy)
                                                .exterior.coords).T)
        ring = [[round(a, 9), round(b, 9)] for a, b in zip(lon.tolist(), lat.tolist(), strict=True)]
        features.append({"type": "Feature", "properties": {"RATE": STRIPE_RATES_KG_HA[i % 4]},
                         "geometry": {"type": "Polygon", "coordinates": [ring]}})
    with open(os.path.join(HERE, "stripes_along_travel.geojson"), "w") as fh:
        json.dump({"type": "FeatureCollection", "features": features}, fh)


def _write_unit_geotiff(filename, seed, rate_range, rate_step, unit):
    """Write synthetic zones as a WGS84 GeoTIFF whose numbers are read in `unit` (not kg/ha)."""
    import rasterio

    crs, bounds = field_bounds_utm()
    zones = synthetic.zones(bounds=bounds, crs=crs, cell_size_m=2.0, seed=seed, n_zones=5,
                            rate_range_kg_ha=rate_range, rate_step_kg_ha=rate_step)
    wgs = zones.reproject("EPSG:4326", cell_size_m=3.0)
    rates = np.where(np.isnan(wgs.rates_kg_ha), -1.0, wgs.rates_kg_ha).astype(np.float32)
    with rasterio.open(os.path.join(HERE, filename), "w", driver="GTiff", width=wgs.cols,
                       height=wgs.rows, count=1, dtype="float32", crs="EPSG:4326", transform=wgs.transform,
                       nodata=-1.0) as dst:
        dst.write(rates, 1)
        dst.units = (unit,)


def write_lb_ac_geotiff():
    _write_unit_geotiff("zones_lb_ac.tif", seed=9, rate_range=(90.0, 210.0), rate_step=15.0, unit="lb/ac")


def write_l_ha_geotiff():
    _write_unit_geotiff("zones_l_ha.tif", seed=26, rate_range=(140.0, 220.0), rate_step=20.0, unit="L/ha")


if __name__ == "__main__":
    write_isoxml()
    write_shapefile()
    write_stripes()
    write_lb_ac_geotiff()
    write_l_ha_geotiff()
