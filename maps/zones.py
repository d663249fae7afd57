"""Rate-zone maps: polygons with a rate attribute (ESRI shapefile, zipped or not, or GeoJSON),
rasterized to a grid with area-weighted values at zone edges.

Polygons are read straight into vertex arrays (the .shp binary is parsed with numpy; no per-polygon
geometry objects) and burnt with `maps.rasterize` on a grid `s` times finer than the target in each
direction (s = 8, less for very large grids); each cell then takes the mean rate of its covered
sub-cells. The area weights are thus exact to 1/s^2 of a cell; a cell only partly covered takes the
mean over its covered part (the field edge is not diluted with zeros); a cell not covered at all is
nodata. Where zones overlap, the later feature wins. The grid keeps the zones' rates
(`maps.Grid.zone_rates_kg_ha`): a cell on a zone edge holds a mean of two that neither zone asks for.
"""

from __future__ import annotations

import io
import json
import math
import os
import posixpath
import struct
import warnings
from dataclasses import dataclass, replace

import numpy as np
import shapefile
from affine import Affine

from vrsim.common import MapError, check_positive, files
from vrsim.maps.crs import WGS84, as_crs, crs_from_prj, metres_per_unit, transform_xy, utm_crs_for
from vrsim.maps.grid import DEFAULT_MAX_CELLS, Grid, check_size
from vrsim.maps.rasterize import rasterize_rings
from vrsim.maps.units import map_unit, unit_in_name
from vrsim.maps.warn import MapWarning

DEFAULT_CELL_SIZE_M = 5.0
# Attribute names farm software uses for the rate, tried in this order (case-insensitive).
RATE_NAMES = ("rate_kg_ha", "rate", "kg_ha", "kgha", "rx_rate", "target_rate", "tgt_rate", "targetrate",
              "app_rate", "apprate", "application_rate", "dose", "prescription", "rx", "value")
SUPERSAMPLE = 8
MAX_FINE_CELLS = 16_000_000  # 64 MB of int32 zone indices


@dataclass
class _Rings:
    """Polygon rings of many features as flat arrays (see `maps.rasterize.rasterize_rings`)."""

    x: np.ndarray
    y: np.ndarray
    ring_start: np.ndarray  # (r + 1,) vertex offsets
    ring_owner: np.ndarray  # (r,) feature of each ring

    @classmethod
    def from_lists(cls, rings: list[np.ndarray], owners: list[int]) -> _Rings:
        """From a list of (n, 2) vertex arrays and the feature index of each."""
        if not rings:
            return cls(np.empty(0), np.empty(0), np.zeros(1, dtype=np.int64), np.empty(0, dtype=np.int64))
        xy = np.concatenate(rings)
        start = np.concatenate(([0], np.cumsum([len(r) for r in rings])))
        return cls(xy[:, 0].copy(), xy[:, 1].copy(), start, np.asarray(owners, dtype=np.int64))


def read_zones(path: str, rate_field: str | None = None, cell_size_m: float | None = None, crs=None,
               max_cells: int | None = DEFAULT_MAX_CELLS, unit: str | None = None) -> Grid:
    """Read a shapefile (.shp or .zip) or GeoJSON of rate-zone polygons and rasterize it.

    Parameters
    ----------
    path : str
        ``.shp``, ``.zip`` (a zipped shapefile) or ``.geojson``/``.json``.
    rate_field : str, optional
        The attribute holding the rate; guessed from common names (or a name stating a unit, like
        ``Rate_lb_ac``) when None.
    cell_size_m : float, optional
        Cell size of the grid, metres (default 5). Zones in lon/lat are rasterized in the UTM zone of
        their centre.
    crs : pyproj.CRS or str, optional
        CRS of a shapefile without ``.prj`` (required then). GeoJSON without a ``crs`` member is
        WGS84 (RFC 7946).
    unit : str, optional
        The rates' unit, when the file does not state it: in the attribute's name (``Rate_lb_ac``,
        ``Rate (lb/ac)``) or in a John Deere ``...-Deere-Metadata.json`` beside the shapefile.
    """
    kind = "geojson" if path.lower().endswith((".geojson", ".json")) else "shapefile"
    if kind == "geojson":
        rings, values_of, fields, src_crs = _geojson_rings(path)
    else:
        rings, values_of, fields, src_crs = _shapefile_rings(path, crs)
    if rings.ring_owner.size == 0:
        raise MapError(f"{path}: no polygon features")
    field_name = _pick_rate_field(path, fields, rate_field)
    rates = _rates(path, values_of(field_name), field_name)
    stated, key = stated_unit(path, field_name, kind)
    unit = map_unit(path, stated, unit, key)
    grid = _rasterize_zones(rings, rates, src_crs, cell_size_m, source=path, format=kind, max_cells=max_cells)
    return replace(grid, unit=unit, map_unit=unit)


def stated_unit(path: str, name: str, kind: str, layer: str | None = None) -> tuple[str | None, str]:
    """(the unit the file states for attribute `name`, where): in the name, or in the John Deere
    metadata of a shapefile (of `layer`, in a zip or folder of several); (None, "") when none."""
    if unit_in_name(name):
        return unit_in_name(name), f"attribute {name!r}"
    if kind == "shapefile":
        from vrsim.maps.pointlog import deere_units
        from vrsim.maps.vector import gdal_source

        stem = os.path.splitext(os.path.basename(gdal_source(path, layer)[0]))[0]
        stated = deere_units(path, stem).get(name.lower())
        if stated:
            return stated, f"Deere metadata of {name!r}"
    return None, ""


def _rasterize_zones(rings: _Rings, rates, crs, cell_size_m: float | None = None, source: str = "zones",
                    format: str = "zones", max_cells: int | None = DEFAULT_MAX_CELLS) -> Grid:
    """Rasterize polygon rings (in `crs`) with per-feature rates (kg/ha) to an area-weighted grid."""
    cell = DEFAULT_CELL_SIZE_M if cell_size_m is None else cell_size_m
    check_positive(cell, f"{source}: cell_size_m", MapError)
    crs = as_crs(crs)
    x, y = rings.x, rings.y
    if x.size == 0 or not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise MapError(f"{source}: polygons without vertices or with non-finite coordinates")
    if crs.is_geographic:
        dst = utm_crs_for(0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max()))
        x, y = transform_xy(x, y, crs, dst)
        crs = dst
    size = cell / metres_per_unit(crs)
    west, north = math.floor(x.min() / size) * size, math.ceil(y.max() / size) * size
    cols = max(1, math.ceil((x.max() - west) / size - 1e-9))
    rows = max(1, math.ceil((north - y.min()) / size - 1e-9))
    check_size(rows, cols, max_cells, f"{source}: rasterized at {cell} m")
    s = max(1, min(SUPERSAMPLE, int(math.sqrt(MAX_FINE_CELLS / (rows * cols)))))
    fine = rasterize_rings(x, y, rings.ring_start, rings.ring_owner, west, north, size / s,
                           rows * s, cols * s)
    table = np.append(np.asarray(rates, dtype=np.float64), np.nan)  # index -1 -> NaN
    out = np.empty((rows, cols))
    band = max(1, 4_000_000 // (cols * s * s))  # coarse rows per pass: bounded temporaries
    for r0 in range(0, rows, band):
        r1 = min(rows, r0 + band)
        values = table[fine[r0 * s:r1 * s]].reshape(r1 - r0, s, cols, s)
        covered = (~np.isnan(values)).sum(axis=(1, 3))
        total = np.nansum(values, axis=(1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            out[r0:r1] = np.where(covered > 0, total / covered, np.nan)
    # The zones' own rates beside the cells: an edge cell's mean of two zones is no rate of the map's.
    return Grid(out, Affine(size, 0.0, west, 0.0, -size, north), crs, source=source, format=format,
                zone_rates_kg_ha=rates)


def rate_field_choice(fields: dict[str, bool], rate_field: str | None = None) -> tuple[str | None, str]:
    """(the attribute read as the rate, why) among `fields` (name -> numeric): the user's, else a name
    farm software uses for the rate (`RATE_NAMES`), else the one numeric attribute whose name states a
    rate unit, else the only numeric one; (None, why not) when none of these tells."""
    if rate_field is not None:
        return (rate_field, "named (rate_field / --rate-field)") if rate_field in fields else \
            (None, f"no attribute {rate_field!r} (rate_field / --rate-field)")
    lower = {name.lower(): name for name in fields}
    for candidate in RATE_NAMES:
        if candidate in lower:  # by name even if not numeric: the error then names the bad value
            return lower[candidate], f"its name is one farm software gives the rate ({candidate!r})"
    numeric = [name for name, is_num in fields.items() if is_num]
    with_unit = [name for name in numeric if unit_in_name(name)]
    if len(with_unit) == 1:  # "Rate_lb_ac": the one attribute that states a rate unit
        return with_unit[0], "the one numeric attribute whose name states a rate unit"
    if len(numeric) == 1:
        return numeric[0], "its only numeric attribute"
    return None, (f"cannot tell which attribute is the rate; numeric attributes: "
                  f"{files.shown(numeric, 200) if numeric else 'none'}; name one with rate_field= / "
                  "--rate-field")


def _pick_rate_field(path: str, fields: dict[str, bool], rate_field: str | None) -> str:
    """The rate attribute (`rate_field_choice`), or a MapError saying why none."""
    name, why = rate_field_choice(fields, rate_field)
    if name is None and rate_field is not None:
        raise MapError(f"{path}: {why}; attributes: {files.shown(sorted(fields), 200)}")
    if name is None:
        raise MapError(f"{path}: {why}")
    if why == "its only numeric attribute":
        warnings.warn(f"{path}: using attribute {name!r} as the rate (its only numeric one)",
                      MapWarning, stacklevel=3)
    return name


def _rates(path: str, values: list, name: str) -> np.ndarray:
    out = np.empty(len(values))
    for i, value in enumerate(values):
        try:
            out[i] = float(value)
        except (TypeError, ValueError):
            raise MapError(f"{path}: feature {i}: rate attribute {name!r} = {files.shown(value)} is not a "
                           "number") from None
        if not math.isfinite(out[i]) or out[i] < 0:
            raise MapError(f"{path}: feature {i}: rate attribute {name!r} = {files.shown(value)}: rates must "
                           "be finite and not negative")
    return out


# ---------------------------------------------------------------------- shapefile
POLYGON_TYPES = (shapefile.POLYGON, shapefile.POLYGONZ, shapefile.POLYGONM)


def _shapefile_rings(path: str, crs):
    parts = _shapefile_parts(path)
    if crs is None and parts["prj"] is None:
        raise MapError(f"{path}: the shapefile has no .prj, so its CRS is unknown; give one (crs= / --crs)")
    src_crs = as_crs(crs, "crs") if parts["prj"] is None else \
        crs_from_prj(parts["prj"].read().decode("utf-8", "replace"), f"{path}: .prj")
    dbf_errors = (shapefile.ShapefileException, ValueError, struct.error, EOFError, UnicodeDecodeError)
    try:
        reader = shapefile.Reader(dbf=parts["dbf"])
        fields = {f[0]: f[1] in ("N", "F") for f in reader.fields[1:]}
        n_records = reader.numRecords
    except dbf_errors as exc:
        raise MapError(f"{path}: damaged .dbf: {exc}") from None
    rings, owners, keep = _parse_shp(parts["shp"].read(), path)
    if len(keep) and keep[-1] >= n_records:
        raise MapError(f"{path}: the .shp has more features than the .dbf has records ({n_records})")

    def values_of(name: str) -> list:
        # Only the rate column: parsing every attribute of every record costs seconds on big files.
        try:
            column = [rec[0] for rec in reader.iterRecords(fields=[name])]
        except dbf_errors as exc:
            raise MapError(f"{path}: damaged .dbf: {exc}") from None
        return [column[i] for i in keep]

    return _Rings.from_lists(rings, owners), values_of, fields, src_crs


def _parse_shp(data: bytes, path: str):
    """Rings of the polygon records of a .shp file, parsed with struct/numpy (no per-ring objects).

    Returns (rings, owner of each ring, index in the file of each kept feature); null shapes are
    skipped, any other non-polygon shape is refused.
    """
    if len(data) < 100 or struct.unpack_from(">i", data, 0)[0] != 9994:
        raise MapError(f"{path}: the .shp is not a shapefile (bad header)")
    rings, owners, keep = [], [], []
    pos, index = 100, 0
    while pos + 8 <= len(data):
        length = struct.unpack_from(">i", data, pos + 4)[0] * 2
        body = pos + 8
        if length < 4 or body + length > len(data):
            raise MapError(f"{path}: damaged .shp: record {index} runs past the end of the file")
        kind = struct.unpack_from("<i", data, body)[0]
        if kind in POLYGON_TYPES:
            n_parts, n_points = struct.unpack_from("<2i", data, body + 36)
            parts_at = body + 44
            points_at = parts_at + 4 * n_parts
            if n_parts < 0 or n_points < 0 or points_at + 16 * n_points > body + length:
                raise MapError(f"{path}: damaged .shp: record {index} declares {n_parts} parts and "
                               f"{n_points} points that do not fit it")
            points = np.frombuffer(data, "<f8", 2 * n_points, points_at).reshape(n_points, 2)
            feature = len(keep)
            if n_parts == 1:  # the common case, without the parts bookkeeping
                rings.append(points)
                owners.append(feature)
            else:
                bounds = (*struct.unpack_from(f"<{n_parts}i", data, parts_at), n_points)
                ordered = all(a <= b for a, b in zip(bounds, bounds[1:], strict=False))
                if bounds[0] != 0 or not ordered:
                    raise MapError(f"{path}: damaged .shp: record {index} has part offsets {bounds[:-1]}")
                for a, b in zip(bounds[:-1], bounds[1:], strict=False):
                    rings.append(points[a:b])
                    owners.append(feature)
            keep.append(index)
        elif kind != shapefile.NULL:
            name = shapefile.SHAPETYPE_LOOKUP.get(kind, f"type {kind}")
            raise MapError(f"{path}: feature {index} is a {name}, not a polygon: rate zones must be polygons")
        pos = body + length
        index += 1
    return rings, owners, keep


def shapefile_polygons(path: str, layer: str | None = None):
    """The polygon features of a shapefile (``.shp``, a ``.zip`` or folder holding one: `layer` names
    it among several, as `maps.vector.gdal_source` does, whose checks it passes first) as shapely
    geometries, read without GDAL: the ``.shp`` parsed as `read_zones` parses it, a feature's rings made
    its polygons by the shapefile's rule (clockwise: a polygon; counter-clockwise: a hole of the one
    holding it); null shapes left out. Returns (polygons, the ``.prj``'s text or None, the layer's name)."""
    import shapely

    from vrsim.maps.vector import gdal_source

    source = gdal_source(path, layer)[0]
    member = None
    if path.lower().endswith(".zip"):   # "/vsizip/<the checked zip>/<member>"
        member = source[len(f"/vsizip/{files.gdal_path(path, MapError)}/"):]
    parts = _shapefile_parts(path if member is not None else source, member)
    rings, owners, _ = _parse_shp(parts["shp"].read(), path)
    owners = np.asarray(owners, dtype=np.int64)
    count = np.bincount(owners, minlength=int(owners.max(initial=-1)) + 1)
    polygons = np.empty(count.size, dtype=object)
    single = np.flatnonzero(count[owners] == 1)   # rings that are a feature's only one
    if single.size:
        lengths = np.array([len(rings[i]) for i in single])
        coords = np.concatenate([rings[i] for i in single])
        lines = shapely.linearrings(coords, indices=np.repeat(np.arange(single.size), lengths))
        polygons[owners[single]] = shapely.polygons(lines)
    for feature in np.flatnonzero(count > 1):
        polygons[feature] = _polygon_of_rings([rings[i] for i in np.flatnonzero(owners == feature)])
    prj = parts["prj"].read().decode("utf-8", "replace") if parts["prj"] is not None else None
    stem = os.path.splitext(posixpath.basename(member) if member else os.path.basename(source))[0]
    return polygons, prj, stem


def _polygon_of_rings(rings: list[np.ndarray]):
    """A feature of several rings as one polygon or a multipolygon: its clockwise rings the polygons
    (all of them where none is), each counter-clockwise one a hole of the first that holds it."""
    import shapely

    def signed_area(r):
        return 0.5 * float(np.dot(r[:-1, 0], r[1:, 1]) - np.dot(r[1:, 0], r[:-1, 1]))

    outer = [r for r in rings if signed_area(r) < 0] or rings
    holes = [r for r in rings if signed_area(r) >= 0] if len(outer) < len(rings) else []
    shells = [shapely.Polygon(r) for r in outer]
    inner = [[] for _ in outer]
    for hole in holes:
        at = next((k for k, p in enumerate(shells) if p.contains(shapely.Point(hole[0]))), None)
        if at is not None:
            inner[at].append(hole)
    polygons = [shapely.Polygon(r, h) for r, h in zip(outer, inner, strict=True)]
    return polygons[0] if len(polygons) == 1 else shapely.MultiPolygon(polygons)


def _shapefile_parts(path: str, member: str | None = None) -> dict:
    """Contents of .shp, .dbf, .shx (optional) and .prj (optional), from a folder or a zip (its
    `member` .shp, else its first), as in-memory files: nothing stays open once this returns."""
    if not os.path.exists(path):
        raise MapError(f"{path}: no such file")
    exts = (".shp", ".dbf", ".shx", ".prj")
    if path.lower().endswith(".zip"):
        with files.open_zip(path, MapError) as z:
            shps = [n for n in z.namelist() if n.lower().endswith(".shp") and not n.startswith("__MACOSX")]
            if not shps:
                raise MapError(f"{path}: the zip archive holds no .shp file")
            if member is not None:
                shps = [member]
            if len(shps) > 1:
                warnings.warn(f"{path}: {len(shps)} shapefiles in the archive; reading {shps[0]}", MapWarning,
                              stacklevel=4)
            stem = shps[0][:-4]
            members = {n.lower(): n for n in z.namelist()}
            names = {ext: members.get((stem + ext).lower()) for ext in exts}
            parts = {ext[1:]: io.BytesIO(files.read_member(z, name, path, MapError)) if name else None
                     for ext, name in names.items()}
    else:
        stem = path[:-4] if path.lower().endswith(".shp") else path
        folder = os.path.dirname(os.path.abspath(stem))
        members = {n.lower(): os.path.join(folder, n) for n in os.listdir(folder)}
        base = os.path.basename(stem)
        parts = {ext[1:]: io.BytesIO(files.read_bytes(members[(base + ext).lower()], error=MapError))
                 if (base + ext).lower() in members else None for ext in exts}
    for ext, what in (("shp", "geometry"), ("dbf", "attributes, including the rate")):
        if parts[ext] is None:
            raise MapError(f"{path}: the shapefile's .{ext} ({what}) is missing")
    return parts


# ---------------------------------------------------------------------- GeoJSON
def load_geojson(path: str) -> dict:
    """Parse a GeoJSON file into a dict, MapError on anything but a JSON object."""
    data = files.read_bytes(path, "geojson", MapError)
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise MapError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("type") not in ("FeatureCollection", "Feature"):
        raise MapError(f"{path}: not a GeoJSON FeatureCollection or Feature")
    return doc


def geojson_crs(doc: dict, path: str):
    """The CRS a GeoJSON declares with the (pre-RFC 7946) ``crs`` member, else WGS84."""
    member = doc.get("crs")
    if member is None:
        return WGS84
    try:
        return as_crs(member["properties"]["name"], f"{path}: crs")
    except (KeyError, TypeError):
        raise MapError(f"{path}: crs member {files.shown(member)} is not "
                       "{'type': 'name', 'properties': {'name': ...}}") from None


def geojson_features(doc: dict, path: str) -> list[dict]:
    feats = doc.get("features") if doc["type"] == "FeatureCollection" else [doc]
    if not isinstance(feats, list) or not all(isinstance(f, dict) for f in feats):
        raise MapError(f"{path}: 'features' is not a list of objects")
    return feats


def _geojson_rings(path: str):
    doc = load_geojson(path)
    rings, owners, records, fields = [], [], [], {}
    for i, feat in enumerate(geojson_features(doc, path)):
        geom = feat.get("geometry")
        props = feat.get("properties") or {}
        if not isinstance(props, dict):
            raise MapError(f"{path}: feature {i}: properties is not an object")
        if not geom:
            continue  # a feature without geometry covers nothing
        kind = geom.get("type") if isinstance(geom, dict) else None
        if kind not in ("Polygon", "MultiPolygon"):
            raise MapError(f"{path}: feature {i} is a {kind}, not a polygon: rate zones must be polygons")
        polygons = [geom.get("coordinates")] if kind == "Polygon" else geom.get("coordinates")
        try:
            feature_rings = [np.asarray(ring, dtype=np.float64)[:, :2] for poly in polygons for ring in poly]
        except (TypeError, ValueError, IndexError):
            raise MapError(f"{path}: feature {i}: coordinates are not lists of [x, y] positions") from None
        rings.extend(feature_rings)
        owners.extend([len(records)] * len(feature_rings))
        records.append(props)
        for key, value in props.items():
            is_num = isinstance(value, (int, float)) and not isinstance(value, bool)
            fields[key] = fields.get(key, True) and is_num
    return (_Rings.from_lists(rings, owners), lambda name: [rec.get(name) for rec in records], fields,
            geojson_crs(doc, path))
