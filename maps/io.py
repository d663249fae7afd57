"""`read_map` and `write_map`: one entry point for every supported format, chosen by the file."""

from __future__ import annotations

import os
import posixpath
import tempfile

from vrsim.common import MapError, files
from vrsim.maps.grid import DEFAULT_MAX_CELLS, Grid

READ_FORMATS = "GeoTIFF (.tif/.tiff), ISOXML TASKDATA (folder, TASKDATA.XML or .zip), shapefile (.shp or " \
               "zipped), GeoJSON zones or points (.geojson/.json), CSV points (.csv)"
WRITE_FORMATS = ".tif/.tiff (GeoTIFF), a TASKDATA folder, .../TASKDATA.XML or .zip (ISOXML grid type 2), " \
                ".shp/.shp.zip (shapefile zones), .geojson/.csv (points)"


def read_map(path, rate_field: str | None = None, cell_size_m: float | None = None, crs=None,
             max_cells: int | None = DEFAULT_MAX_CELLS, layer: str | None = None,
             product: str | None = None, unit: str | None = None, density_kg_l: float | None = None) -> Grid:
    """Read a prescription map in any supported format into a `Grid`, its rates in kg/ha.

    A map's unit is the one it states (GeoTIFF band unit or ``unit`` tag, ISOXML DDI, an attribute
    name like ``Rate_lb_ac``, John Deere metadata) or `unit`; a map with neither is refused. Rates
    are converted to kg/ha once, here (`Grid.to_kg_ha`; the grid keeps its `map_unit` to show them
    in); a volume rate only with `density_kg_l`, else the grid stays in its volume unit.

    Parameters
    ----------
    path : str or os.PathLike
        The map: GeoTIFF, ISOXML TASKDATA (folder, TASKDATA.XML or .zip), shapefile (.shp or a .zip
        holding one), GeoJSON (rate-zone polygons or a point table), CSV point table.
    rate_field : str, optional
        Attribute holding the rate in zone and point files; guessed when None.
    cell_size_m : float, optional
        Rasterization cell size for zone files, metres (default 5).
    crs : pyproj.CRS or str, optional
        CRS of a file that does not say (a shapefile without .prj, a raster without CRS, a CSV of
        x/y without .prj).
    max_cells : int or None
        Refuse grids larger than this (default 200 million cells); None: no cap.
    layer : str, optional
        The shapefile of a zip or folder holding several (required then: they are listed).
    product : str, optional
        The product (``PDTn`` or its name) of a TASKDATA grid holding several (required then); a
        TASKDATA takes `rate_field` as the product when `product` is not given.
    unit : str, optional
        The rates' unit (`maps.units.rate_unit`), for a file that does not state it (one that does
        must agree).
    density_kg_l : float, optional
        The product's density, kg/L: converts a volume rate (L/ha, gal/ac) to kg/ha.

    Raises
    ------
    MapError
        For every unreadable, inconsistent or unsupported input, naming the file and the problem.
    """
    path = os.fspath(path)
    return _read(path, rate_field, cell_size_m, crs, max_cells, layer, product, unit).to_kg_ha(density_kg_l)


def _read(path: str, rate_field, cell_size_m, crs, max_cells, layer, product, unit) -> Grid:
    """The map at `path` in the unit it states or `unit` (`read_map`)."""
    files.refuse_vsi(path, MapError)
    if not os.path.exists(path):
        raise MapError(f"{path}: no such file or folder")
    lower = path.lower()
    if os.path.isdir(path) and not _is_taskdata_folder(path):
        return _read_layer(path, layer, rate_field, cell_size_m, crs, max_cells, unit)
    if os.path.isdir(path) or lower.endswith(".xml"):
        from vrsim.maps.isoxml import read_isoxml
        from vrsim.maps.timelog import is_lone_timelog

        if is_lone_timelog(path):
            raise MapError(f"{path}: a TimeLog (what a machine logged), not a prescription map; "
                           "`vrsim evaluate` reads it")

        return read_isoxml(path, max_cells=max_cells, product=product or rate_field, unit=unit)
    if lower.endswith(".zip"):
        return _read_zip(path, rate_field, cell_size_m, crs, max_cells, layer, product, unit)
    if lower.endswith((".tif", ".tiff", ".gtiff")):
        from vrsim.maps.geotiff import read_geotiff

        return read_geotiff(path, crs=crs, max_cells=max_cells, unit=unit)
    if lower.endswith(".shp"):
        from vrsim.maps.zones import read_zones

        return read_zones(path, rate_field, cell_size_m, crs, max_cells, unit)
    if lower.endswith((".geojson", ".json")):
        from vrsim.maps.points import geojson_is_points, read_geojson_points
        from vrsim.maps.zones import load_geojson, read_zones

        doc = load_geojson(path)
        if geojson_is_points(doc, path):
            return read_geojson_points(path, doc, rate_field, max_cells, unit)
        return read_zones(path, rate_field, cell_size_m, crs, max_cells, unit)
    if lower.endswith(".csv"):
        from vrsim.maps.points import read_csv

        return read_csv(path, rate_field, crs, max_cells, unit)
    raise MapError(f"{path}: unknown map format (by extension); vrsim reads {READ_FORMATS}")


def _read_zip(path, rate_field, cell_size_m, crs, max_cells, layer, product, unit) -> Grid:
    """A .zip is an ISOXML TASKDATA or a zipped shapefile: tell by what it holds."""
    with files.open_zip(path, MapError) as z:
        names = [n.lower() for n in z.namelist()]
    if any(os.path.basename(n) == "taskdata.xml" for n in names):
        from vrsim.maps.isoxml import read_isoxml

        return read_isoxml(path, max_cells=max_cells, product=product or rate_field, unit=unit)
    if any(n.endswith(".shp") for n in names):
        return _read_layer(path, layer, rate_field, cell_size_m, crs, max_cells, unit)
    raise MapError(f"{path}: the zip archive holds neither a TASKDATA.XML nor a .shp")


def _is_taskdata_folder(path: str) -> bool:
    """A folder read as a TASKDATA: one with a TASKDATA.XML (or a TASKDATA folder), or no shapefile."""
    names = [n.lower() for n in os.listdir(path)]
    return "taskdata.xml" in names or "taskdata" in names or not any(n.endswith(".shp") for n in names)


def _read_layer(path, layer, rate_field, cell_size_m, crs, max_cells, unit) -> Grid:
    """The rate zones of one shapefile of a zip or folder: the only one, or `layer` (several: named)."""
    from dataclasses import replace

    from vrsim.maps.vector import gdal_source
    from vrsim.maps.zones import read_zones

    source, _, _ = gdal_source(path, layer)  # refuses several layers and none named, or a wrong name
    if os.path.isdir(path) or layer is None:  # a folder's shapefile, or a zip's only one
        return read_zones(source if os.path.isdir(path) else path, rate_field, cell_size_m, crs, max_cells,
                          unit)
    member = source.split(f"{os.path.realpath(path)}/", 1)[1]
    with tempfile.TemporaryDirectory(prefix="vrsim-layer-") as tmp:
        stem = member[:-4]
        metadata = f"{stem}-deere-metadata.json".lower()  # the units of its attributes (maps.pointlog)
        with files.open_zip(path, MapError) as z:
            for name in z.namelist():
                if name[:-4] == stem and name[-4:].lower() in (".shp", ".shx", ".dbf", ".prj", ".cpg"):
                    copy = "layer" + name[-4:].lower()
                elif name.lower() == metadata:
                    copy = "layer-Deere-Metadata.json"
                else:
                    continue
                with open(os.path.join(tmp, copy), "wb") as fh:
                    fh.write(files.read_member(z, name, path, MapError))
        where = f"{path}:{posixpath.basename(stem)}"
        try:
            grid = read_zones(os.path.join(tmp, "layer.shp"), rate_field, cell_size_m, crs, max_cells, unit)
        except MapError as exc:  # named as the user knows it, not by the temporary copy
            raise MapError(str(exc).replace(os.path.join(tmp, "layer.shp"), where)) from None
    return replace(grid, source=where)


def write_map(grid: Grid, path, like: str | None = None) -> None:
    """Write a grid; the format follows the extension (of `like` if given: the final name of a file
    written under a temporary one).

    ``.tif``/``.tiff``: GeoTIFF. A folder (a path without extension, or an existing folder) or
    ``.../TASKDATA.XML``: ISOXML TASKDATA.XML + a GRDnnnnn.BIN beside it (grid type 2, DDI 6, WGS84;
    other CRSs are reprojected; never overwriting, see `maps.isoxml.write_isoxml`). ``.zip``: the
    same in an archive. ``.shp`` or ``.shp.zip``: a polygon shapefile prescription, zipped or not
    (`maps.shapefile_rx`). ``.geojson`` / ``.json`` / ``.csv``: one point per cell centre. Rates
    are written in the grid's `map_unit`, which the file states (ISOXML: DDI 6, in kg/ha).
    """
    from vrsim.maps.shapefile_rx import is_shapefile_path

    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise MapError(f"{path}: folder {folder} does not exist")
    lower = os.fspath(like or path).lower()
    grid = grid.as_map_unit()  # files state the map's own unit
    if is_shapefile_path(lower):
        from vrsim.maps.shapefile_rx import write_shapefile

        def writer(grid, path):
            write_shapefile(grid, path, like=like)
    elif lower.endswith((".tif", ".tiff")):
        from vrsim.maps.geotiff import write_geotiff as writer
    elif lower.endswith((".xml", ".zip")) or os.path.isdir(path) or not os.path.splitext(path)[1]:
        from vrsim.maps.isoxml import write_isoxml as writer  # DDI 0006: in kg/ha

        grid = grid.to_kg_ha(grid.density_kg_l)
    elif lower.endswith((".geojson", ".json")):
        from vrsim.maps.points import write_geojson as writer
    elif lower.endswith(".csv"):
        from vrsim.maps.points import write_csv as writer
    else:
        raise MapError(f"{path}: unknown output format (by extension); vrsim writes {WRITE_FORMATS}")
    try:
        writer(grid, path)
    except OSError as exc:
        raise MapError(f"{path}: cannot write: {exc}") from None
