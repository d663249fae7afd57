"""A field: its boundary polygon in a local metric CRS (the UTM zone of its centroid).

Boundaries come from GeoJSON, a shapefile (``.shp`` or a zipped one), KML/KMZ, an ISOXML TASKDATA's
partfield (`vehicle.boundary_files`), a list of WGS84 vertices, or a rectangle by size; holes (inner
rings) are kept, and the coverage path and the field's cells leave them out. Everything downstream
(coverage path, SUMO network, GNSS) works in metres in ``field.crs``; `Field.to_wgs84` /
`Field.from_wgs84` convert positions for output.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np
import pyproj
import shapely
from shapely.geometry import MultiPolygon, Polygon, shape
from shapely.validation import explain_validity

from vrsim.common import files
from vrsim.common.checks import check_number, check_positive
from vrsim.common.errors import VehicleError

WGS84 = pyproj.CRS.from_epsg(4326)
# Larger than any field farmed as one: a bigger boundary is a unit or CRS mistake, and its coverage
# path and grid would not fit in memory (a 1e9 m square would need ~1e8 swaths).
MAX_FIELD_AREA_HA = 10_000.0
MAX_FIELD_SIDE_M = 50_000.0  # bounding-box side; UTM's scale error also grows past a few tens of km
# A field dissolved from many polygons (`Field.from_polygons`) drops parts and holes smaller than this:
# the slivers that zones which do not quite meet leave, not a headland's worth of ground (a 10 m square).
SLIVER_M2 = 100.0


class FieldWarning(UserWarning):
    """A boundary used with a repair: an invalid ring made valid, slivers dropped (one line)."""


def _utm_crs(lon: float, lat: float) -> pyproj.CRS:
    """The WGS84 / UTM zone CRS holding (lon, lat) in degrees (EPSG 326xx north, 327xx south)."""
    zone = int((lon + 180.0) // 6.0) % 60 + 1
    return pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


@dataclass(eq=False)
class Field:
    """A field boundary in metres.

    Attributes
    ----------
    polygon : shapely.Polygon
        Boundary (with holes for obstacles, if any) in ``crs`` coordinates, metres.
    crs : pyproj.CRS
        The UTM zone of the boundary's centroid.
    name : str
        A label for reports (the file stem, or "rectangle"/"field").
    """

    polygon: Polygon
    crs: pyproj.CRS
    name: str = "field"
    _to_wgs: pyproj.Transformer = dc_field(init=False, repr=False)
    _from_wgs: pyproj.Transformer = dc_field(init=False, repr=False)

    def __post_init__(self):
        self.polygon = _validated(self.polygon, self.name)
        self._to_wgs = pyproj.Transformer.from_crs(self.crs, WGS84, always_xy=True)
        self._from_wgs = pyproj.Transformer.from_crs(WGS84, self.crs, always_xy=True)

    # --- constructors ----------------------------------------------------------------------------
    @classmethod
    def from_lonlat(cls, coords, name: str = "field") -> Field:
        """A field from boundary vertices ``[(lon, lat), ...]`` in WGS84 degrees (closed or not)."""
        try:
            lonlat = np.asarray(coords, dtype=float)
        except (TypeError, ValueError) as exc:
            raise VehicleError(f"field {name!r}: coords must be (lon, lat) pairs: {exc}") from None
        if lonlat.ndim != 2 or lonlat.shape[1] != 2 or len(lonlat) < 3:
            raise VehicleError(f"field {name!r}: coords must be at least 3 (lon, lat) pairs, "
                               f"got shape {lonlat.shape}")
        return cls._from_geometry(Polygon(lonlat), WGS84, name)

    @classmethod
    def rectangle(cls, width_m: float, length_m: float, lat: float = 52.0, lon: float = 10.0,
                  name: str = "rectangle") -> Field:
        """An axis-aligned ``width_m`` (east) x ``length_m`` (north) field with its south-west corner
        at (lon, lat) in degrees."""
        for arg, value in (("width_m", width_m), ("length_m", length_m)):
            check_positive(value, f"field rectangle: {arg}", VehicleError, unit="m")
            if value > MAX_FIELD_SIDE_M:
                raise VehicleError(f"field rectangle: {arg} = {value:g} m is over the cap of "
                                   f"{MAX_FIELD_SIDE_M:g} m (vehicle.field.MAX_FIELD_SIDE_M)")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (lat, lon)) \
                or not (-80.0 <= lat <= 84.0 and -180.0 <= lon <= 180.0):
            raise VehicleError(f"field rectangle: lat={lat!r}, lon={lon!r} is outside UTM coverage")
        crs = _utm_crs(lon, lat)
        x0, y0 = pyproj.Transformer.from_crs(WGS84, crs, always_xy=True).transform(lon, lat)
        return cls(shapely.box(x0, y0, x0 + width_m, y0 + length_m), crs, name)

    @classmethod
    def from_polygons(cls, polygons, crs, name: str = "field", sliver_m2: float = SLIVER_M2,
                      where: str | None = None) -> Field:
        """One field from many polygons: a prescription's zones, a boundary file's parts.

        The polygons are projected to the UTM zone of their centre, repaired there (an invalid ring,
        which may become invalid only once projected, with ``shapely.make_valid``), dissolved
        (``shapely.union_all``, holes kept), and parts and holes smaller than `sliver_m2` dropped. A
        repair or a drop is said in one `FieldWarning`.

        Parameters
        ----------
        polygons : sequence of shapely geometries
            Polygons or multipolygons in `crs` (None and empty ones are skipped).
        crs : anything `pyproj.CRS.from_user_input` takes
            The polygons' CRS.
        name : str
            The field's label.
        sliver_m2 : float
            Parts and holes of the union under this area are dropped, m^2 (0: none).
        where : str, optional
            What errors and the warning name (default: the field's name).

        Raises
        ------
        VehicleError
            No polygon; a union of several parts above `sliver_m2` (listed); the caps of `_check_extent`.
        """
        where = where or f"field {name!r}"
        check_number(sliver_m2, f"{where}: sliver_m2", VehicleError, lo=0.0, unit="m^2")
        array = np.asarray([g for g in polygons if g is not None and not g.is_empty], dtype=object)
        if array.size == 0:
            raise VehicleError(f"{where}: no polygon to make a field of")
        try:
            src = pyproj.CRS.from_user_input(crs)
        except pyproj.exceptions.CRSError as exc:
            raise VehicleError(f"{where}: crs={crs!r} is not a CRS: {exc}") from None
        minx, miny, maxx, maxy = shapely.total_bounds(array)
        lon, lat = pyproj.Transformer.from_crs(src, WGS84, always_xy=True).transform(
            0.5 * (minx + maxx), 0.5 * (miny + maxy))
        if not (math.isfinite(lon) and math.isfinite(lat)):
            raise VehicleError(f"{where}: the polygons' centre does not map to WGS84")
        utm = _utm_crs(lon, lat)
        to_utm = pyproj.Transformer.from_crs(src, utm, always_xy=True)
        projected = shapely.transform(array, lambda xy: np.column_stack(to_utm.transform(xy[:, 0], xy[:, 1])))
        _check_extent(shapely.box(*shapely.total_bounds(projected)), where)
        dissolved, notes = _dissolve(projected, sliver_m2)
        if notes:
            warnings.warn(f"{where}: {'; '.join(notes)}", FieldWarning, stacklevel=2)
        if len(dissolved) != 1:
            areas = ", ".join(f"{p.area / 1e4:,.2f} ha" for p in sorted(dissolved, key=lambda p: -p.area)[:6])
            raise VehicleError(f"{where}: the polygons' union is {len(dissolved)} separate parts ({areas}"
                               f"{', ...' if len(dissolved) > 6 else ''}) above the sliver area of "
                               f"{sliver_m2:g} m^2; a field is one: give a boundary of one polygon, or a "
                               "sliver area above the parts to drop")
        return cls(dissolved[0], utm, name)

    @classmethod
    def from_file(cls, path: str, crs=None, partfield: str | None = None, union: bool = False,
                  sliver_m2: float = SLIVER_M2) -> Field:
        """Read a boundary from GeoJSON (``.geojson``/``.json``), a shapefile (``.shp`` or ``.zip``),
        KML (``.kml``/``.kmz``) or an ISOXML TASKDATA (folder, ``TASKDATA.XML`` or a ``.zip`` holding
        one: its partfield boundary).

        Parameters
        ----------
        path : str
            The file. One polygon, holes included (or a multipolygon with one part); several only
            with `union`.
        crs : anything `pyproj.CRS.from_user_input` takes, optional
            The coordinates' CRS. Default: the shapefile's ``.prj``, the GeoJSON ``crs`` member, or
            WGS84 if the coordinates look like degrees (KML and ISOXML: WGS84).
        partfield : str, optional
            The partfield (``PFDn`` or its designator) of a TASKDATA with several, or the placemark
            (its name) of a KML with several.
        union : bool
            A GeoJSON or shapefile of several polygons (a prescription's zones) becomes their union
            (`from_polygons`, with `sliver_m2`); without it such a file is refused, saying how many
            polygons it holds and what to do (never one of them taken in silence).
        """
        from vrsim.vehicle import boundary_files
        if isinstance(path, (str, os.PathLike)):
            files.refuse_vsi(os.fspath(path), VehicleError, label=f"field file {path}")  # no GDAL /vsi path
        if not isinstance(path, (str, os.PathLike)) or not os.path.exists(path):
            raise VehicleError(f"field file {path}: not found")
        path = os.fspath(path)
        if not os.path.isdir(path):
            files.check_file(path, error=VehicleError)  # a regular file within its byte cap, or refused
        ext = os.path.splitext(path)[1].lower()
        if ext in (".geojson", ".json"):
            geom, file_crs = _read_geojson(path)
        elif ext in (".kml", ".kmz"):
            geom, file_crs = boundary_files.read_kml(path, partfield), WGS84
        elif boundary_files.is_taskdata(path):
            geom, file_crs = boundary_files.read_partfield(path, partfield), WGS84
        elif ext in (".shp", ".zip"):
            geom, file_crs = _read_shapefile(path)
        else:
            raise VehicleError(f"field file {path}: unknown extension {ext!r} (want .geojson, .json, .shp, "
                               ".zip, .kml, .kmz or an ISOXML TASKDATA)")
        if crs is not None:
            try:
                file_crs = pyproj.CRS.from_user_input(crs)
            except pyproj.exceptions.CRSError as exc:
                raise VehicleError(f"field file {path}: crs={crs!r} is not a CRS: {exc}") from None
        name, where = os.path.splitext(os.path.basename(path))[0], f"field file {path}"
        if isinstance(geom, list):  # a GeoJSON's or shapefile's polygon features
            if len(geom) > 1 and not union:
                raise VehicleError(f"{where}: holds {len(geom):,} polygons (a prescription's zones?); a "
                                   "field is one: take their union ([field] union = true), take the "
                                   "prescription's zones ([field] from_map = true), or give a file of one "
                                   "polygon")
            if len(geom) > 1:
                return cls.from_polygons(geom, file_crs or _degrees_or_refused(geom, path), name,
                                         sliver_m2, where)
            geom = geom[0]
        if geom.is_empty:
            raise VehicleError(f"field file {path}: boundary is empty")
        return cls._from_geometry(geom, file_crs or _degrees_or_refused([geom], path), name, where)

    @classmethod
    def _from_geometry(cls, geom, src_crs: pyproj.CRS, name: str, where: str | None = None) -> Field:
        where = where or f"field {name!r}"
        geom = _single_polygon(geom, where)
        if geom.is_empty:
            raise VehicleError(f"{where}: boundary is empty")
        to_wgs = pyproj.Transformer.from_crs(src_crs, WGS84, always_xy=True)
        lon, lat = to_wgs.transform(*geom.centroid.coords[0])
        if not (math.isfinite(lon) and math.isfinite(lat)):
            raise VehicleError(f"{where}: centroid {geom.centroid.coords[0]} does not map to WGS84")
        crs = _utm_crs(lon, lat)
        if not geom.is_valid:  # name the defect before projecting can change it
            raise VehicleError(f"{where}: boundary is invalid: {explain_validity(geom)}")
        to_utm = pyproj.Transformer.from_crs(src_crs, crs, always_xy=True)
        projected = shapely.transform(geom, lambda xy: np.column_stack(to_utm.transform(xy[:, 0], xy[:, 1])))
        _check_extent(projected, where)
        return cls(projected, crs, name)

    # --- properties and conversions --------------------------------------------------------------
    @property
    def area_ha(self) -> float:
        """Boundary area in hectares."""
        return self.polygon.area / 1e4

    def to_wgs84(self, x_m, y_m):
        """(lon, lat) degrees of local (x, y) metres; arrays or scalars."""
        return self._to_wgs.transform(x_m, y_m)

    def from_wgs84(self, lon, lat):
        """Local (x, y) metres of (lon, lat) degrees; arrays or scalars."""
        return self._from_wgs.transform(lon, lat)

    def to_geojson(self) -> dict:
        """The boundary as a GeoJSON Feature in WGS84 (RFC 7946: exterior counter-clockwise, holes
        clockwise), its name, area (ha) and UTM zone as properties: what QGIS or Google Earth shows."""
        from shapely.geometry import mapping

        wgs = shapely.transform(self.polygon, lambda xy: np.column_stack(self.to_wgs84(xy[:, 0], xy[:, 1])))
        props = {"name": self.name, "area_ha": round(self.area_ha, 4), "holes": len(self.polygon.interiors),
                 "utm_crs": f"EPSG:{self.crs.to_epsg()}"}
        return {"type": "Feature", "properties": props, "geometry": mapping(shapely.orient_polygons(wgs))}

    def longest_edge_heading_deg(self) -> float:
        """Compass bearing (degrees clockwise from north, in [0, 180)) of the boundary's longest edge."""
        xy = np.asarray(self.polygon.exterior.coords)
        d = np.diff(xy, axis=0)
        k = int(np.argmax(np.hypot(d[:, 0], d[:, 1])))
        return math.degrees(math.atan2(d[k, 0], d[k, 1])) % 180.0


def _degrees_or_refused(geoms: list, path: str) -> pyproj.CRS:
    """WGS84 for a file with no CRS whose coordinates look like degrees; else refused."""
    minx, miny, maxx, maxy = shapely.total_bounds(np.asarray(geoms, dtype=object))
    if not (-180 <= minx <= maxx <= 180 and -90 <= miny <= maxy <= 90):
        raise VehicleError(f"field file {path}: no CRS given and coordinates {(minx, miny, maxx, maxy)} "
                           "are not degrees; pass crs=")
    return WGS84


def _dissolve(polygons: np.ndarray, sliver_m2: float) -> tuple[list[Polygon], list[str]]:
    """The union of `polygons` (metres) as its parts, invalid ones made valid first, parts and holes
    under `sliver_m2` dropped; and what was repaired or dropped, as phrases."""
    notes = []
    invalid = ~shapely.is_valid(polygons)
    if invalid.any():
        first = shapely.is_valid_reason(polygons[invalid][0])
        polygons = polygons.copy()
        polygons[invalid] = shapely.make_valid(polygons[invalid])
        notes.append(f"{int(invalid.sum()):,} invalid ring{'s' if invalid.sum() > 1 else ''} repaired with "
                     f"shapely's make_valid (the first: {first}, in UTM metres)")
    parts = shapely.get_parts(shapely.get_parts(polygons))  # collections of make_valid, then multi-parts
    parts = parts[shapely.get_type_id(parts) == 3]  # polygons (make_valid may leave lines, points)
    union = shapely.union_all(parts)
    kept, small_parts, small_holes = [], 0, 0
    for part in shapely.get_parts(union):
        if part.area < sliver_m2:
            small_parts += 1
            continue
        holes = [ring for ring in part.interiors if Polygon(ring).area >= sliver_m2]
        small_holes += len(part.interiors) - len(holes)
        kept.append(Polygon(part.exterior, holes))
    if small_parts or small_holes:
        notes.append(f"dropped {small_parts} part{'s' * (small_parts != 1)} and {small_holes} "
                     f"hole{'s' * (small_holes != 1)} under {sliver_m2:g} m^2 (slivers)")
    return kept, notes


def _validated(polygon, name: str) -> Polygon:
    where = f"field {name!r}"
    polygon = _single_polygon(polygon, where)
    if polygon.is_empty or polygon.area <= 0:
        raise VehicleError(f"{where}: boundary is empty (area 0)")
    _check_extent(polygon, where)
    if not polygon.is_valid:
        raise VehicleError(f"{where}: boundary is invalid: {explain_validity(polygon)}")
    return shapely.normalize(polygon)


def _check_extent(polygon, where: str) -> None:
    """Refuse a boundary (in metres) larger than `MAX_FIELD_AREA_HA` or wider than `MAX_FIELD_SIDE_M`,
    before anything is planned or allocated over it."""
    minx, miny, maxx, maxy = polygon.bounds
    area_ha, width_m, height_m = polygon.area / 1e4, maxx - minx, maxy - miny
    if not all(map(math.isfinite, (area_ha, width_m, height_m))):
        raise VehicleError(f"{where}: boundary does not project to finite metres (bounds {polygon.bounds})")
    if area_ha > MAX_FIELD_AREA_HA or max(width_m, height_m) > MAX_FIELD_SIDE_M:
        raise VehicleError(f"{where}: boundary of {area_ha:,.0f} ha in a {width_m:,.0f} m x "
                           f"{height_m:,.0f} m box is over the caps of {MAX_FIELD_AREA_HA:,.0f} ha and "
                           f"{MAX_FIELD_SIDE_M:,.0f} m per side (vehicle.field.MAX_FIELD_AREA_HA / "
                           "MAX_FIELD_SIDE_M); wrong units or CRS?")


def _single_polygon(geom, where: str) -> Polygon:
    if isinstance(geom, MultiPolygon):
        parts = [g for g in geom.geoms if not g.is_empty]
        if len(parts) != 1:
            raise VehicleError(f"{where}: boundary has {len(parts)} separate parts; give one polygon")
        geom = parts[0]
    if not isinstance(geom, Polygon):
        raise VehicleError(f"{where}: boundary must be a polygon, got {geom.geom_type}")
    return geom


def _read_geojson(path: str):
    data = files.read_bytes(path, "geojson", VehicleError)
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise VehicleError(f"field file {path}: not readable GeoJSON: {exc}") from None
    crs = None
    member = doc.get("crs") if isinstance(doc, dict) else None
    props = member.get("properties") if isinstance(member, dict) else None
    name = props.get("name") if isinstance(props, dict) else None
    if member and not name:
        raise VehicleError(f"field file {path}: crs member {files.shown(member)} is not "
                           "{'type': 'name', 'properties': {'name': ...}}")
    if name:
        try:
            crs = pyproj.CRS.from_user_input(name)
        except (pyproj.exceptions.CRSError, TypeError):
            raise VehicleError(f"field file {path}: crs name {files.shown(name)} is not a CRS") from None
    geoms = _geojson_geometries(doc)
    polys = [g for g in geoms if isinstance(g, dict) and g.get("type") in ("Polygon", "MultiPolygon")]
    if not polys:
        raise VehicleError(f"field file {path}: no Polygon or MultiPolygon geometry in it")
    return [_geojson_polygon(poly, path) for poly in polys], crs


def _geojson_polygon(poly: dict, path: str):
    """A GeoJSON Polygon or MultiPolygon as shapely's, each ring checked to close."""
    try:
        geom = shape(poly)
        rings = [np.asarray(ring, dtype=float) for part in ([poly["coordinates"]] if poly["type"] ==
                 "Polygon" else poly["coordinates"]) for ring in part]
    except (ValueError, TypeError, AttributeError, IndexError, KeyError) as exc:
        raise VehicleError(f"field file {path}: bad polygon coordinates: {exc}") from None
    for ring in rings:  # GeoJSON repeats a ring's first position last; shapely would close it silently
        if ring.ndim == 2 and len(ring) and not np.array_equal(ring[0], ring[-1]):
            raise VehicleError(f"field file {path}: a ring does not close: it starts at "
                               f"{tuple(ring[0].tolist())} and ends at {tuple(ring[-1].tolist())}")
    return geom


def _geojson_geometries(doc):
    if not isinstance(doc, dict):
        return []
    kind = doc.get("type")
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            return []
        return [f.get("geometry") for f in features if isinstance(f, dict)]
    if kind == "Feature":
        return [doc.get("geometry")]
    return [doc]


def _read_shapefile(path: str):
    import struct
    import zipfile

    import shapefile  # pyshp; only needed here

    # What pyshp lets through on a damaged file: a bad zip, a short or garbled header or record.
    damaged = (shapefile.ShapefileException, zipfile.BadZipFile, struct.error, EOFError, ValueError, OSError)
    if path.lower().endswith(".zip"):
        files.open_zip(path, VehicleError).close()  # member count and sizes, before pyshp inflates them
    else:
        files.check_siblings(path, VehicleError)  # the .shx, .dbf and .prj pyshp and we open by name
    try:
        with shapefile.Reader(path) as reader:
            shapes = [s for s in reader.shapes() if s.shapeType in (shapefile.POLYGON, shapefile.POLYGONZ,
                                                                    shapefile.POLYGONM)]
            if not shapes:
                raise VehicleError(f"field file {path}: no polygon shape in it")
            geom = [shape(s.__geo_interface__) for s in shapes]
    except damaged as exc:
        raise VehicleError(f"field file {path}: not a readable shapefile: {exc}") from None
    return geom, _read_prj(path)


def _read_prj(path: str):
    """The CRS from the ``.prj`` beside a ``.shp`` or inside a ``.zip``, else None."""
    wkt = None
    if path.lower().endswith(".zip"):
        with files.open_zip(path, VehicleError) as z:
            prj = [n for n in z.namelist() if n.lower().endswith(".prj")]
            if prj:
                wkt = files.read_member(z, prj[0], path, VehicleError).decode("utf-8", "replace")
    else:
        prj = os.path.splitext(path)[0] + ".prj"
        if os.path.exists(prj):
            wkt = files.read_bytes(prj, "prj", VehicleError).decode("utf-8", "replace")
    if not wkt:
        return None
    try:
        return pyproj.CRS.from_wkt(wkt)
    except pyproj.exceptions.CRSError:
        raise VehicleError(f"field file {path}: its .prj is not a CRS") from None
