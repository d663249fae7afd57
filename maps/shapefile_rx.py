"""Prescriptions written as shapefiles, the format John Deere Operations Center and AgOpenGPS take.

One polygon per zone: each connected run of cells of one rate (rounded to 0.01 of the map's unit) is
one polygon (`rasterio.features.shapes`, exact cell edges, holes kept); a cell without a rate
(nodata) gets no polygon, so a terminal applies nothing there. The rate attribute is named with its
unit (``Rate_kg_ha``; 10 characters at most, as the .dbf allows). Polygons stay in the map's CRS,
which the ``.prj`` states. Written through pyogrio (GDAL/OGR); ``.shp.zip`` zips the files of one
shapefile, as the terminals' import takes them.
"""

from __future__ import annotations

import os
import tempfile
import zipfile

import numpy as np

from vrsim.common import MapError
from vrsim.maps.grid import Grid
from vrsim.maps.vector import ogr

ZIPPED = ".shp.zip"
CENTI = 100  # rates are written in 0.01 of their unit, exact through the integer zone labels


def is_shapefile_path(path: str) -> bool:
    """True for a path the shapefile writer takes: ``.shp`` or ``.shp.zip``."""
    return path.lower().endswith((".shp", ZIPPED))


def _rate_field_name(unit: str) -> str:
    """The rate attribute named with its unit: ``Rate_kg_ha``, ``Rate_L_ha``, ``R_gal_ac`` (<= 10 chars)."""
    name = "Rate_" + unit.replace("/", "_")
    return name if len(name) <= 10 else ("R_" + unit.replace("/", "_"))[:10]


def _zone_polygons(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """(polygons as WKB, rate of each) of the grid's connected runs of cells of one rate."""
    import shapely
    from rasterio.features import shapes

    rates = grid.rates_kg_ha
    ok = np.isfinite(rates)
    labels = np.where(ok, np.rint(np.where(ok, rates, 0.0) * CENTI), 0)
    if ok.any() and np.abs(labels[ok]).max() > np.iinfo(np.int32).max:
        raise MapError(f"{grid.source or 'the map'}: a rate of {np.nanmax(rates)} {grid.unit} is too large "
                       "for a shapefile prescription")
    found = list(shapes(labels.astype(np.int32), mask=ok, transform=grid.transform, connectivity=4))
    polygons = shapely.to_wkb(np.array([shapely.geometry.shape(g) for g, _ in found], dtype=object))
    return polygons, np.array([v for _, v in found], dtype=np.float64) / CENTI


def write_shapefile(grid: Grid, path: str, like: str | None = None) -> str:
    """Write `grid` as a polygon shapefile prescription: ``.shp`` (with .shx, .dbf, .prj, .cpg beside
    it) or ``.shp.zip`` (those files zipped), by the name of `like` if given (the final name of a file
    written under a temporary one; it also names the zip's members). Returns `path`.

    Raises
    ------
    MapError
        A map of differences (not rates), a map with no rate, another extension.
    """
    pyogrio = ogr()

    path = os.fspath(path)
    final = os.fspath(like or path)
    if not is_shapefile_path(final):
        raise MapError(f"{final}: a shapefile prescription is written as .shp or {ZIPPED}")
    if grid.quantity != "rate":
        raise MapError(f"{final}: a prescription holds rates; {grid.source or 'the grid'} holds differences "
                       "of rates")
    polygons, rates = _zone_polygons(grid)
    if not rates.size:
        raise MapError(f"{final}: {grid.source or 'the grid'} has no cell with a rate: nothing to write")
    field = _rate_field_name(grid.unit)
    crs = grid.crs.to_wkt()

    def write(shp: str) -> None:
        pyogrio.raw.write(shp, polygons, [rates], [field], driver="ESRI Shapefile", geometry_type="Polygon",
                          crs=crs, encoding="UTF-8")

    if final.lower().endswith(".shp"):
        write(path)
        return path
    stem = os.path.basename(final)[:-len(ZIPPED)]
    with tempfile.TemporaryDirectory(prefix="vrsim-shp-") as tmp:
        write(os.path.join(tmp, stem + ".shp"))
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for name in sorted(os.listdir(tmp)):
                z.write(os.path.join(tmp, name), name)
    return path
