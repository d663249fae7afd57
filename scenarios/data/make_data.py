"""Writes the example field boundary (GeoJSON, WGS84) and prescription (GeoTIFF in the field's UTM
zone) that `geojson_field_geotiff_map.toml` reads. Checked in; rerun only to change them.

    .venv/bin/python scenarios/data/make_data.py
"""

import json
import os

import pyproj

from vrsim.maps import synthetic, utm_crs_for, write_map

HERE = os.path.dirname(os.path.abspath(__file__))
LON, LAT = 9.35, 53.2
# An irregular field of about 7 ha, vertices in metres east/north of (LON, LAT).
OUTLINE_M = [(0, 0), (300, -10), (330, 150), (250, 260), (90, 240), (-15, 130)]


def main():
    crs = utm_crs_for(LON, LAT)
    fwd = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    inv = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    x0, y0 = fwd.transform(LON, LAT)
    ring = [inv.transform(x0 + dx, y0 + dy) for dx, dy in OUTLINE_M]
    ring.append(ring[0])
    doc = {"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"name": "example field"},
        "geometry": {"type": "Polygon", "coordinates": [[[round(x, 8), round(y, 8)] for x, y in ring]]}}]}
    with open(os.path.join(HERE, "field.geojson"), "w") as fh:
        json.dump(doc, fh, indent=1)
    bounds = (x0 - 40, y0 - 50, x0 + 370, y0 + 300)
    grid = synthetic.zones(bounds=bounds, crs=crs, cell_size_m=3.0, seed=9, n_zones=5,
                           rate_range_kg_ha=(90.0, 230.0), rate_step_kg_ha=10.0)
    write_map(grid, os.path.join(HERE, "prescription.tif"))


if __name__ == "__main__":
    main()
