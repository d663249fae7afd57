"""As-applied point logs: one point per logged record, with applied and target rate.

`PointLog` holds such a log as columns in any CRS and unit; it is what vrsim reads from a machine's
export (a point shapefile, zipped or not, or a GeoPackage, e.g. a John Deere Operations Center
export; or a TASKDATA's TimeLogs, see `maps.taskdata`) and what it writes for a run
(`maps.pointlog_write.write_points`: GeoPackage or zipped shapefile, WGS84).

The vector files are read and written through pyogrio (GDAL/OGR); nothing here parses them by hand.

Fields vrsim writes (10 characters at most, so the shapefile keeps them):

==========  ====================================================================================
time        when the record was logged (GeoPackage: DateTime; shapefile: ISO 8601 text)
time_s      seconds since the first record
hdg_deg     heading, degrees clockwise from north
speed_m_s   ground speed, m/s
width_m     working (swath) width in use, m
work        implement work state, 1 on, 0 off (ISO 11783 DDI 141)
sections    number of sections on
target      target (setpoint) rate, in ``rate_unit``
applied     applied (actual) rate, in ``rate_unit``
rate_unit   the unit of both rates, e.g. ``kg/ha``
gnss        ISO 11783 position status (0 no fix ... 4 RTK fixed ... 8 simulated, 15 not available)
==========  ====================================================================================
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import re
import warnings
from dataclasses import dataclass, replace

import numpy as np
import pyproj

from vrsim.common import MapError, files
from vrsim.maps.crs import WGS84, as_crs, transform_xy
from vrsim.maps.units import RATE_UNITS, convert_rate
from vrsim.maps.warn import MapWarning

NOT_AVAILABLE = 15  # ISO 11783 position status: not available

LENGTH_M = {"m": 1.0, "ft": 0.3048, "in": 0.0254, "cm": 0.01, "mm": 0.001}


@dataclass(eq=False)
class PointLog:
    """An as-applied log as columns: point i is element i of every array.

    Parameters
    ----------
    x, y : array_like, shape (n,)
        Positions in `crs` (x = easting or longitude); NaN where the record has no position.
    crs : pyproj.CRS or str
        CRS of x and y.
    applied, target : array_like, shape (n,)
        Applied (actual) and target (setpoint) rate in `unit`; NaN where not logged.
    unit : str
        Unit of the rates, e.g. ``"kg/ha"``, ``"gal/ac"``; ``""`` when the source does not say.
    time_s : array_like, shape (n,), optional
        Seconds since `start` (or since the first record); NaN when the source has no times.
    start : numpy.datetime64, optional
        The absolute time of ``time_s == 0`` (as the source logged it, no time zone).
    heading_deg, speed_m_s, width_m : array_like or float, optional
        Heading (degrees clockwise from north), ground speed and working width in use; NaN unknown.
    work_on : array_like of bool, optional
        Whether the implement was applying (default: True everywhere).
    sections_on : array_like of bool, shape (n, s), optional
        Per-section states, section 1 the leftmost (default: none known, shape (n, 0)).
    gnss_status : array_like of int, optional
        ISO 11783 position status per record (default 15, not available).
    section_id : array_like of int, optional
        The section a record is of, in a log with one record per section (John Deere's
        ``SECTIONID``); -1 where the record is the whole machine's (default).
    distance_m : array_like, optional
        Distance travelled since the previous record, m (John Deere's ``DISTANCE``); NaN unknown.
    source, format : str
        Where it came from, and ``"shapefile"``, ``"gpkg"``, ``"taskdata"`` or ``"run"``.
    """

    x: np.ndarray
    y: np.ndarray
    crs: pyproj.CRS
    applied: np.ndarray
    target: np.ndarray
    unit: str = "kg/ha"
    time_s: np.ndarray | None = None
    start: np.datetime64 | None = None
    heading_deg: np.ndarray | None = None
    speed_m_s: np.ndarray | None = None
    width_m: np.ndarray | None = None
    work_on: np.ndarray | None = None
    sections_on: np.ndarray | None = None
    gnss_status: np.ndarray | None = None
    section_id: np.ndarray | None = None
    distance_m: np.ndarray | None = None
    source: str = ""
    format: str = ""

    def __post_init__(self):
        self.x = np.asarray(self.x, dtype=np.float64).ravel()
        n = self.x.size
        self.crs = as_crs(self.crs, f"{self._where()}: crs")
        for name in ("y", "applied", "target", "time_s", "heading_deg", "speed_m_s", "width_m", "distance_m"):
            value = getattr(self, name)
            setattr(self, name, self._column(name, np.nan if value is None else value, np.float64, n))
        self.work_on = self._column("work_on", True if self.work_on is None else self.work_on, bool, n)
        status = NOT_AVAILABLE if self.gnss_status is None else self.gnss_status
        self.gnss_status = self._column("gnss_status", status, np.uint8, n)
        self.section_id = self._column("section_id", -1 if self.section_id is None else self.section_id,
                                       np.int64, n)
        sections = np.zeros((n, 0), dtype=bool) if self.sections_on is None else self.sections_on
        sections = np.asarray(sections, dtype=bool)
        if sections.ndim != 2 or sections.shape[0] != n:
            raise MapError(f"{self._where()}: sections_on must have shape ({n}, sections), got "
                           f"{sections.shape}")
        self.sections_on = sections
        if self.start is not None:
            self.start = np.datetime64(self.start, "ms")

    def _where(self) -> str:
        return self.source or "point log"

    def _column(self, name: str, value, dtype, n: int) -> np.ndarray:
        arr = np.asarray(value, dtype=dtype)
        if arr.ndim == 0:
            return np.full(n, arr, dtype=dtype)
        if arr.shape != (n,):
            raise MapError(f"{self._where()}: {name} has shape {arr.shape}, the log has {n} points")
        return arr

    @property
    def points(self) -> int:
        return int(self.x.size)

    @property
    def time(self) -> np.ndarray | None:
        """Absolute time of each point (datetime64[ms]), or None without `start`."""
        if self.start is None:
            return None
        ms = np.where(np.isfinite(self.time_s), np.rint(self.time_s * 1000.0), 0).astype(np.int64)
        return np.where(np.isfinite(self.time_s), self.start + ms.astype("timedelta64[ms]"),
                        np.datetime64("NaT", "ms"))

    def lonlat(self) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 longitude and latitude of every point."""
        lon, lat = transform_xy(self.x, self.y, self.crs, WGS84)
        return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)

    def thin(self, period_s: float) -> PointLog:
        """The first record of every `period_s` of `time_s` (1.0: a 1 Hz log, as terminals log)."""
        if not (isinstance(period_s, (int, float)) and math.isfinite(period_s) and period_s > 0):
            raise MapError(f"{self._where()}: thin: period_s={period_s!r} must be a positive number")
        # A tick's time over the period is a whole number give or take rounding (0.15 / 0.05 =
        # 2.9999999999999996): nudged, so thinning at the tick's own period keeps every tick.
        slot = np.floor(self.time_s / period_s + 1e-9)
        keep = np.flatnonzero(np.isfinite(slot) & np.concatenate(([True], slot[1:] != slot[:-1])))
        return replace(self, **{name: getattr(self, name)[keep] for name in COLUMNS})

    def in_unit(self, unit: str, density_kg_l: float | None = None,
                seed_mass_g: float | None = None) -> PointLog:
        """This log with its rates converted to `unit` (see `convert_rate`; between a volume and a
        mass rate with the product's `density_kg_l`, a count and a mass rate with `seed_mass_g`)."""
        if unit == self.unit:
            return self
        per = (density_kg_l, seed_mass_g)
        return replace(self, applied=convert_rate(self.applied, self.unit, unit, *per),
                       target=convert_rate(self.target, self.unit, unit, *per), unit=unit)


COLUMNS = ("x", "y", "applied", "target", "time_s", "heading_deg", "speed_m_s", "width_m", "work_on",
           "sections_on", "gnss_status", "section_id", "distance_m")  # the per-record arrays of a PointLog


# ---------------------------------------------------------------------- reading
# Attribute names of applied and target rate, tried in this order (case-insensitive). John Deere's
# .dbf fills all 11 bytes of a field name ("AppliedRate", no terminator), which GDAL reads whole and
# 10-character readers as "AppliedRat"; vrsim writes applied/target.
APPLIED_NAMES = ("applied", "appliedrate", "appliedrat", "applied_rate", "applied_kg_ha", "actualrate",
                 "actual_rate", "as_applied", "rate_applied")
TARGET_NAMES = ("target", "targetrate", "targetrat", "target_rate", "target_kg_ha", "setpoint",
                "setpointrate", "rx_rate", "prescribed")
# Time attributes: a DateTime one first; among text ones ISO 8601 IsoTime first (Deere's Time drops
# the milliseconds).
TIME_NAMES = ("time", "isotime", "timestamp", "datetime", "date_time")
TEXT_TIME_NAMES = ("isotime", "timestamp", "datetime", "date_time", "time")
HEADING_NAMES = ("hdg_deg", "heading", "heading_deg", "course")
SPEED_NAMES = ("speed_m_s", "speed")
WIDTH_NAMES = ("width_m", "swathwidth", "swath_width", "swathwidt", "width")
WORK_NAMES = ("work", "work_on", "work_state", "implement_on")
SECTION_NAMES = ("sectionid", "section_id", "section")
DISTANCE_NAMES = ("distance", "distance_m", "dist")
DEERE_UNIT = re.compile(r"([A-Za-z]+)(-?\d+)")


def read_point_log(path, rate_field: str | None = None, target_field: str | None = None,
                   time_field: str | None = None, unit: str | None = None, crs=None,
                   layer: str | None = None, product: str | None = None,
                   target_optional: bool = False) -> PointLog:
    """Read an as-applied log: a TASKDATA with TimeLogs, a point shapefile (zipped or not) or GeoPackage.

    Parameters
    ----------
    path : str or os.PathLike
        A TASKDATA (folder, TASKDATA.XML or a .zip holding one), ``.shp``, ``.zip`` holding a
        ``.shp``, a folder of shapefiles, or ``.gpkg``.
    rate_field, target_field : str, optional
        The attributes holding the applied and target rate; found by name when None
        (``AppliedRate``/``AppliedRat``, ``TargetRate``, vrsim's ``applied``/``target``, ...). For a
        TASKDATA, the applied rate's DDI (``"7"``, ``"0x0007"``; default DDI 7, else DDI 2), and the
        target's.
    time_field : str, optional
        The attribute holding the time (default: ``time``, ``IsoTime``, ...).
    unit : str, optional
        Unit of the rates when the file does not say (a Deere metadata JSON beside or in the archive,
        a ``rate_unit`` attribute, or the TASKDATA's DDI say it).
    crs : pyproj.CRS or str, optional
        CRS of a file that does not declare one.
    layer : str, optional
        The layer of a zip, folder or GeoPackage holding several (listed when none is named); required then.
    product : str, optional
        For a TASKDATA logging the rate of several products: the one to read (`read_taskdata_log`).
    target_optional : bool
        A point file with no target attribute gives NaN targets (its targets come from elsewhere, a
        prescription) instead of an error.
    """
    path = os.fspath(path)
    files.refuse_vsi(path, MapError)
    if not os.path.exists(path):
        raise MapError(f"{path}: no such file or folder")
    from vrsim.maps.taskdata import is_taskdata, read_taskdata_log

    if is_taskdata(path):
        return read_taskdata_log(path, rate_ddi=rate_field, target_ddi=target_field, product=product)
    if not (os.path.isdir(path) or path.lower().endswith((".shp", ".zip", ".gpkg"))):
        raise MapError(f"{path}: an as-applied log must be a TASKDATA, a point shapefile (.shp or .zip) or a "
                       "GeoPackage (.gpkg)")
    return _read_vector(path, rate_field, target_field, time_field, unit, crs, layer, target_optional)


def _read_vector(path, rate_field, target_field, time_field, unit, crs, layer=None,
                 target_optional=False) -> PointLog:
    import shapely

    from vrsim.maps.vector import gdal_source, read_vector

    if not os.path.isdir(path):  # a folder's shapefiles are checked as `read_vector` lists them
        files.check_file(path, error=MapError)  # GDAL opens by name: a FIFO or a device would hang it
        files.check_siblings(path, MapError)
    meta, _, geometry, columns = read_vector(path, layer)  # its signature checked, as GDAL will see it
    fields = dict(zip((str(f) for f in meta["fields"]), columns, strict=True))
    points = shapely.from_wkb(geometry)
    kinds = shapely.get_type_id(points)  # 0: point, -1: no geometry
    if (kinds != 0).any():
        i = int(np.argmax(kinds != 0))
        kind = "no" if kinds[i] < 0 else shapely.get_type_id(points[i]) and points[i].geom_type
        raise MapError(f"{path}: record {i} has {kind} geometry, not a point: an as-applied log must be "
                       "points (export points, not polygons or lines)")
    xy = shapely.get_coordinates(points)
    src_crs = as_crs(meta["crs"], f"{path}: CRS") if meta.get("crs") else None
    if src_crs is None:
        if crs is None:
            raise MapError(f"{path}: the file has no CRS (no .prj); give one (crs= / --crs)")
        src_crs = as_crs(crs, "crs")
    units = deere_units(path, os.path.splitext(os.path.basename(gdal_source(path, layer)[0]))[0])
    applied_name = _pick(path, fields, rate_field, APPLIED_NAMES, "applied rate", "--rate-field")
    no_target = target_optional and target_field is None and _find(fields, TARGET_NAMES) is None
    target_name = None if no_target else _pick(path, fields, target_field, TARGET_NAMES, "target rate",
                                                "--target-field")
    rate_unit = unit or _rate_unit(path, fields, units, applied_name)
    time_s, start = _times(path, fields, time_field)
    work = _optional(path, fields, WORK_NAMES)  # the work state: other than 0 is on; not logged: on
    section = _optional(path, fields, SECTION_NAMES)
    return PointLog(
        xy[:, 0], xy[:, 1], src_crs, applied=_numbers(path, fields[applied_name], applied_name),
        target=np.nan if target_name is None else _numbers(path, fields[target_name], target_name),
        unit=rate_unit, time_s=time_s,
        start=start, heading_deg=_optional(path, fields, HEADING_NAMES),
        speed_m_s=_optional(path, fields, SPEED_NAMES),
        width_m=_length(path, fields, WIDTH_NAMES, units), work_on=None if work is None else work != 0,
        section_id=None if section is None else np.where(np.isfinite(section), section, -1).astype(np.int64),
        distance_m=_length(path, fields, DISTANCE_NAMES, units),
        source=f"{path}:{layer}" if layer else path,
        format="gpkg" if path.lower().endswith(".gpkg") else "shapefile")


def _find(fields: dict, names) -> str | None:
    lower = {name.lower(): name for name in fields}
    return next((lower[n] for n in names if n in lower), None)


def _pick(path, fields: dict, given: str | None, names, what: str, option: str) -> str:
    if given is not None:
        if given not in fields:
            raise MapError(f"{path}: no attribute {given!r} ({what}); attributes: {sorted(fields)}")
        return given
    found = _find(fields, names)
    if found is None:
        raise MapError(f"{path}: cannot tell which attribute is the {what}; attributes: {sorted(fields)}; "
                       f"name it with {option}")
    return found


def _numbers(path, column: np.ndarray, name: str) -> np.ndarray:
    try:
        return np.asarray(column, dtype=np.float64)
    except (TypeError, ValueError):
        bad = next(i for i, v in enumerate(column) if not _is_number(v))
        raise MapError(f"{path}: record {bad}: {name}={column[bad]!r} is not a number") from None


def _is_number(value) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return value is None
    return True


def _optional(path, fields: dict, names) -> np.ndarray | None:
    name = _find(fields, names)
    return None if name is None else _numbers(path, fields[name], name)


def _length(path, fields: dict, names, units: dict) -> np.ndarray | None:
    """A length attribute in metres (the Deere metadata may say it is in feet)."""
    name = _find(fields, names)
    if name is None:
        return None
    unit = units.get(name.lower(), "m")
    if unit not in LENGTH_M:
        raise MapError(f"{path}: attribute {name!r} is in {unit!r}; vrsim reads lengths in "
                       f"{sorted(LENGTH_M)}")
    return _numbers(path, fields[name], name) * LENGTH_M[unit]


def _rate_unit(path, fields: dict, units: dict, applied_name: str) -> str:
    """The rates' unit: a ``rate_unit`` attribute, the Deere metadata, or a unit suffix in the name."""
    column = fields.get(_find(fields, ("rate_unit",)) or "")
    if column is not None:
        values = {str(v) for v in column}
        if len(values) > 1:
            raise MapError(f"{path}: rate_unit holds several units {sorted(values)}; a log has one")
        return values.pop() if values else ""
    if applied_name.lower() in units:
        return units[applied_name.lower()]
    for candidate in RATE_UNITS:
        if applied_name.lower().endswith("_" + candidate.replace("/", "_").lower()):
            return candidate
    warnings.warn(f"{path}: the file does not say the unit of {applied_name!r}; give it with unit= / --unit",
                  MapWarning, stacklevel=4)
    return ""


def _deere_unit(code: str) -> str:
    """A John Deere metadata unit code as vrsim writes units: ``"gal1ac-1"`` -> ``"gal/ac"``."""
    parts = DEERE_UNIT.findall(code)
    if not parts or "".join(u + e for u, e in parts) != code:
        return code
    up = [u + ("" if e == "1" else f"^{e}") for u, e in parts if not e.startswith("-")]
    down = [u + ("" if e == "-1" else f"^{e[1:]}") for u, e in parts if e.startswith("-")]
    return "/".join(["".join(up) or "1", *down])


def deere_units(path: str, stem: str) -> dict[str, str]:
    """Attribute name (lower case) -> unit, from the ``<stem>-Deere-Metadata.json`` of the shapefile
    `stem` (its name without ``.shp``) beside it or in the archive.

    The shapefile cuts attribute names to 10 characters (AppliedRat) while the metadata names them in
    full (AppliedRate), so each unit is filed under its full name and under its first 10 characters.
    """
    text = _metadata_text(path, stem)
    if text is None:
        return {}
    try:
        doc = json.loads(text)
        attributes = doc.get("DataAttributes", [])
        pairs = [(a["Name"], a["Unit"]) for a in attributes if isinstance(a, dict) and "Unit" in a]
    except (ValueError, AttributeError, KeyError, TypeError) as exc:
        raise MapError(f"{path}: the Deere metadata JSON is not readable: {exc}") from None
    units = {}
    for name, code in pairs:
        units[str(name).lower()] = units[str(name)[:10].lower()] = _deere_unit(str(code))
    return units


def _metadata_text(path: str, stem: str) -> str | None:
    suffix = "-deere-metadata.json"
    stem = stem.lower()
    if path.lower().endswith(".zip"):
        with files.open_zip(path, MapError) as z:
            names = [n for n in z.namelist() if os.path.basename(n).lower() == stem + suffix]
            if len(names) != 1:
                return None
            return files.read_member(z, names[0], path, MapError).decode("utf-8", "replace")
    folder = path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))
    for name in os.listdir(folder):
        if name.lower() == stem + suffix:
            data = files.read_bytes(os.path.join(folder, name), "geojson", MapError)
            return data.decode("utf-8", "replace")
    return None


def _times(path, fields: dict, time_field: str | None):
    """(time_s, start) from a DateTime attribute or ISO 8601 / ``M/D/Y h:m:s AM`` text; NaN, None if none."""
    if time_field is not None and time_field not in fields:
        raise MapError(f"{path}: no attribute {time_field!r} (time); attributes: {sorted(fields)}")
    name = time_field or _best_time_field(fields)
    if name is None:
        return None, None
    column = fields[name]
    if np.issubdtype(column.dtype, np.datetime64):
        stamps = column.astype("datetime64[ms]")
    else:
        stamps = np.array([_parse_time(path, i, name, v) for i, v in enumerate(column)],
                          dtype="datetime64[ms]")
    ok = ~np.isnat(stamps)
    if not ok.any():
        return None, None
    start = stamps[ok].min()
    time_s = np.where(ok, (stamps - start).astype("timedelta64[ms]").astype(np.int64) / 1000.0, np.nan)
    return time_s, start


def _best_time_field(fields: dict) -> str | None:
    lower = {name.lower(): name for name in fields}
    for n in TIME_NAMES:
        if n in lower and np.issubdtype(fields[lower[n]].dtype, np.datetime64):
            return lower[n]
    return _find(fields, TEXT_TIME_NAMES)


US_TIME = "%m/%d/%Y %I:%M:%S %p"


def _parse_time(path, i: int, name: str, value) -> np.datetime64:
    if value is None or value == "":
        return np.datetime64("NaT", "ms")
    text = str(value).strip()
    try:
        stamp = dt.datetime.fromisoformat(text)
        if stamp.tzinfo is not None:  # a zone given: as UTC
            stamp = stamp.astimezone(dt.timezone.utc).replace(tzinfo=None)
        return np.datetime64(stamp, "ms")
    except ValueError:
        pass
    try:
        return np.datetime64(dt.datetime.strptime(text, US_TIME), "ms")
    except ValueError:
        raise MapError(f"{path}: record {i}: {name}={value!r} is not a time (ISO 8601 or "
                       "'11/29/2017 4:21:32 PM')") from None
