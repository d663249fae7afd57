"""A zone file as a table: its polygons and attributes as they are, before any rate or unit is read.

`read_zone_table` reads a shapefile (``.shp``, a ``.zip`` holding one, a folder, a ``.gpkg``: through
`maps.vector.read_vector`, signatures checked) or a GeoJSON of polygons; `describe_zones` says what is
in it (`vrsim map info` with no unit: attributes, their values, which one would be read as the rate
and why, the unit if the file states one, zones, area, CRS); the field built from a prescription
(`vehicle.Field.from_polygons`) takes its `ZoneTable.polygons`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pyproj

from vrsim.common import MapError
from vrsim.maps.crs import as_crs, crs_label, utm_crs_for
from vrsim.maps.zones import geojson_crs, geojson_features, load_geojson, rate_field_choice, stated_unit

DISTINCT_SHOWN = 12  # an attribute with at most this many distinct values lists them; else its range
_KINDS = {"i": "integer", "u": "integer", "f": "real", "b": "boolean", "M": "date"}


@dataclass
class ZoneTable:
    """The features of a zone file.

    Attributes
    ----------
    source : str
        The file.
    layer : str
        The layer read (a shapefile's name without ``.shp``; "" for GeoJSON).
    polygons : ndarray of shapely geometries
        Each feature's polygon or multipolygon (as the file has it: rings may be invalid), in `crs`.
    attributes : dict of str to ndarray
        Each attribute's values, one per polygon.
    crs : pyproj.CRS or None
        The polygons' CRS: the file's, or the one given; None when neither says.
    """

    source: str
    layer: str
    polygons: np.ndarray
    attributes: dict
    crs: pyproj.CRS | None

    def is_numeric(self, name: str) -> bool:
        """Whether attribute `name` holds numbers (integers or reals)."""
        return _kind(self.attributes[name]) in ("integer", "real")


def is_zone_file(path: str) -> bool:
    """Whether `read_zone_table` reads `path` by its name: a shapefile, zipped or in a folder, a
    GeoPackage, or GeoJSON (a GeoJSON of points is refused when read)."""
    lower = path.lower()
    if os.path.isdir(path):
        return any(n.lower().endswith(".shp") for n in os.listdir(path))
    if lower.endswith(".zip"):
        from vrsim.common import files

        with files.open_zip(path, MapError) as z:
            names = [n.lower() for n in z.namelist()]
        return any(n.endswith(".shp") for n in names) and not any(
            os.path.basename(n) == "taskdata.xml" for n in names)
    return lower.endswith((".shp", ".gpkg", ".geojson", ".json"))


def read_zone_table(path, layer: str | None = None, crs=None, attributes: bool = True) -> ZoneTable:
    """The polygons and attributes of a zone file.

    Parameters
    ----------
    path : str or os.PathLike
        ``.shp``, a ``.zip`` or folder holding shapefiles, ``.gpkg``, ``.geojson``/``.json``.
    layer : str, optional
        The shapefile (layer) of a file holding several (required then: they are listed).
    crs : pyproj.CRS or str, optional
        The CRS of a file that states none (a shapefile without ``.prj``); over the file's.
    attributes : bool
        Read the attributes too. Without them a shapefile is read without GDAL
        (`maps.zones.shapefile_polygons`, the CRS from its ``.prj`` as `read_zones` reads it): the
        polygons of a field from a prescription (`services.sim.world.field_from_map`), for which GDAL
        would hold 25 MB more for the whole run.

    Raises
    ------
    MapError
        Unreadable file, a feature that is not a polygon, no polygon at all.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MapError(f"{path}: no such file or folder")
    if path.lower().endswith((".geojson", ".json")):
        table = _geojson_table(path)
    elif not attributes and not path.lower().endswith(".gpkg"):
        table = _shapefile_table(path, layer)
    else:
        table = _vector_table(path, layer)
    if crs is not None:
        table.crs = as_crs(crs, "crs")
    alive = np.array([g is not None and not g.is_empty for g in table.polygons], dtype=bool)
    if not alive.any():
        raise MapError(f"{path}: no polygon features")
    table.polygons = table.polygons[alive]
    table.attributes = {k: v[alive] for k, v in table.attributes.items()}
    return table


def _vector_table(path: str, layer: str | None) -> ZoneTable:
    import shapely

    from vrsim.maps.vector import gdal_source, read_vector

    meta, _, wkb, columns = read_vector(path, layer)
    kind = str(meta.get("geometry_type") or "")
    if "polygon" not in kind.lower() and kind.lower() not in ("unknown", ""):
        raise MapError(f"{path}: its features are {kind}s, not a polygon: rate zones must be polygons")
    polygons = shapely.from_wkb(wkb) if len(wkb) else np.empty(0, dtype=object)
    bad = [i for i, g in enumerate(polygons)
           if g is not None and g.geom_type not in ("Polygon", "MultiPolygon")]
    if bad:
        raise MapError(f"{path}: feature {bad[0]} is a {polygons[bad[0]].geom_type}, not a polygon: rate "
                       "zones must be polygons")
    names = [str(n) for n in meta["fields"]]
    crs = pyproj.CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    stem = os.path.splitext(os.path.basename(gdal_source(path, layer)[0]))[0]
    return ZoneTable(path, layer or stem, polygons, dict(zip(names, columns, strict=True)), crs)


def _shapefile_table(path: str, layer: str | None) -> ZoneTable:
    """A shapefile's polygons and CRS without its attributes, read without GDAL."""
    import shapely

    from vrsim.maps.crs import crs_from_prj
    from vrsim.maps.zones import shapefile_polygons

    try:
        polygons, prj, stem = shapefile_polygons(path, layer)
    except (ValueError, shapely.errors.GEOSException):   # rings GEOS makes no polygon of: as GDAL reads them
        return _vector_table(path, layer)
    crs = crs_from_prj(prj, f"{path}: .prj") if prj is not None else None
    return ZoneTable(path, layer or stem, polygons, {}, crs)


def _geojson_table(path: str) -> ZoneTable:
    from shapely.geometry import shape

    doc = load_geojson(path)
    polygons, records = [], []
    for i, feat in enumerate(geojson_features(doc, path)):
        geom, props = feat.get("geometry"), feat.get("properties") or {}
        if not isinstance(props, dict):
            raise MapError(f"{path}: feature {i}: properties is not an object")
        kind = geom.get("type") if isinstance(geom, dict) else None
        if geom and kind not in ("Polygon", "MultiPolygon"):
            raise MapError(f"{path}: feature {i} is a {kind}, not a polygon: rate zones must be polygons")
        try:
            polygons.append(shape(geom) if geom else None)
        except (ValueError, TypeError, AttributeError, IndexError, KeyError) as exc:
            raise MapError(f"{path}: feature {i}: bad polygon coordinates: {exc}") from None
        records.append(props)
    names = list(dict.fromkeys(k for rec in records for k in rec))
    columns = {}
    for name in names:
        values = [rec.get(name) for rec in records]
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool)
                      for v in values if v is not None)
        columns[name] = np.array([np.nan if v is None else v for v in values], dtype=float) if numeric \
            else np.array(values, dtype=object)
    array = np.empty(len(polygons), dtype=object)
    array[:] = polygons
    return ZoneTable(path, "", array, columns, geojson_crs(doc, path))


def _kind(values: np.ndarray) -> str:
    if values.dtype.kind in _KINDS:
        whole = np.isnan(values) | (values == np.round(values)) if values.dtype.kind == "f" else None
        if whole is not None and values.size and whole.all():
            return "real (whole numbers)"
        return _KINDS[values.dtype.kind]
    return "text"


def _values(values: np.ndarray) -> dict:
    """Count of values given, distinct values (at most `DISTINCT_SHOWN`) or range (numbers)."""
    numeric = values.dtype.kind in "iuf"
    given = values[~np.isnan(values)] if values.dtype.kind == "f" else \
        values if numeric else np.array([v for v in values if v is not None and v != ""], dtype=object)
    distinct = np.unique(given.astype(str) if not numeric else given)
    out = {"count": int(given.size), "distinct": int(distinct.size)}
    if distinct.size <= DISTINCT_SHOWN:
        out["values"] = [v.item() if hasattr(v, "item") else str(v) for v in distinct]
    elif numeric:
        out["range"] = [given.min().item(), given.max().item()]
    return out


def describe_zones(table: ZoneTable, rate_field: str | None = None) -> dict:
    """What a zone file holds, with no rate unit needed: what ``vrsim map info`` shows first.

    Returns
    -------
    dict
        ``source``, ``layer``, ``file_crs`` (None: not stated), ``zones`` (polygon features),
        ``zones_area_ha`` (their areas summed in the UTM zone of their centre; None without a CRS),
        ``attributes`` (name -> type, count, distinct, values or range), ``rate_attribute`` (None:
        cannot tell), ``rate_attribute_why``, ``stated_unit`` (None: not stated) and ``stated_in``.
    """
    fields = {name: table.is_numeric(name) for name in table.attributes}
    name, why = rate_field_choice(fields, rate_field)
    kind = "geojson" if table.source.lower().endswith((".geojson", ".json")) else "shapefile"
    unit, where = stated_unit(table.source, name, kind, table.layer or None) if name else (None, "")
    return {
        "source": table.source,
        "layer": table.layer,
        "file_crs": crs_label(table.crs) if table.crs is not None else None,
        "zones": int(len(table.polygons)),
        "zones_area_ha": _area_ha(table),
        "attributes": {n: {"type": _kind(v), **_values(v)} for n, v in table.attributes.items()},
        "rate_attribute": name,
        "rate_attribute_why": why,
        "stated_unit": unit,
        "stated_in": where or None,
    }


def _area_ha(table: ZoneTable) -> float | None:
    """The zones' areas summed (invalid rings repaired first), in the UTM zone of their centre, ha."""
    import shapely

    if table.crs is None:
        return None
    polygons = shapely.make_valid(table.polygons)
    minx, miny, maxx, maxy = shapely.total_bounds(polygons)
    if table.crs.is_geographic:
        utm = utm_crs_for(0.5 * (minx + maxx), 0.5 * (miny + maxy))
        to = pyproj.Transformer.from_crs(table.crs, utm, always_xy=True)
        polygons = shapely.transform(polygons, lambda xy: np.column_stack(to.transform(xy[:, 0], xy[:, 1])))
    return float(shapely.area(polygons).sum() / 1e4)
