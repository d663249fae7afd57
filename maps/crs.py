"""Coordinate reference systems: parsing user input, cached transformers, UTM zones, unit sizes.

Maps arrive in WGS84 lon/lat or in projected CRSs; the simulation works in metres in the field's UTM
zone. Every transformation here uses ``always_xy=True``: x is easting or longitude, y is northing or
latitude, whatever axis order the CRS definition declares.
"""

from __future__ import annotations

import functools

import numpy as np
import pyproj
from pyproj.exceptions import CRSError

from vrsim.common import MapError

WGS84 = pyproj.CRS.from_epsg(4326)


def as_crs(value, what: str = "crs") -> pyproj.CRS:
    """Parse a CRS from anything pyproj understands (``"EPSG:32632"``, WKT, an EPSG int, a CRS).

    Parameters
    ----------
    value : str, int or pyproj.CRS
        The CRS to parse.
    what : str
        Name of the argument or file the value came from, for the error message.

    Raises
    ------
    MapError
        If pyproj cannot make a CRS of it.
    """
    if isinstance(value, pyproj.CRS):
        return value
    try:
        return _cached_crs(value)
    except (CRSError, TypeError, ValueError) as exc:
        raise MapError(f"{what}: {value!r} is not a coordinate reference system ({exc})") from None


@functools.lru_cache(maxsize=64)
def _cached_crs(value) -> pyproj.CRS:
    # CRS parsing costs ~100 us; lookups with crs="EPSG:4326" per call must not pay it every time.
    return pyproj.CRS.from_user_input(value)


_TRANSFORMERS: dict[tuple[int, int], tuple[pyproj.CRS, pyproj.CRS, pyproj.Transformer]] = {}


def transformer(src: pyproj.CRS, dst: pyproj.CRS) -> pyproj.Transformer:
    """A cached ``always_xy`` transformer from `src` to `dst` (building one costs ~1 ms).

    Keyed by object identity, because hashing a pyproj CRS renders its WKT (tens of us); the entry
    keeps both CRS objects alive so their ids cannot be reused.
    """
    key = (id(src), id(dst))
    hit = _TRANSFORMERS.get(key)
    if hit is None:
        if len(_TRANSFORMERS) > 256:
            _TRANSFORMERS.clear()
        hit = (src, dst, pyproj.Transformer.from_crs(src, dst, always_xy=True))
        _TRANSFORMERS[key] = hit
    return hit[2]


def transform_xy(x, y, src: pyproj.CRS, dst: pyproj.CRS) -> tuple[np.ndarray, np.ndarray]:
    """Transform coordinate arrays from `src` to `dst` (x = easting/longitude).

    Returns float64 arrays of the broadcast shape of `x` and `y`; points that cannot be
    transformed come back as inf or NaN (pyproj's convention), which lookups treat as outside.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if src == dst:
        return np.broadcast_arrays(x, y)
    tx, ty = transformer(src, dst).transform(x, y, errcheck=False)
    return np.asarray(tx, dtype=np.float64), np.asarray(ty, dtype=np.float64)


def crs_from_prj(text: str, what: str) -> pyproj.CRS:
    """The CRS of a ``.prj`` (ESRI WKT) file, as its EPSG CRS when it matches one.

    ESRI WKT loses EPSG codes and axis order; matching it back (confidence >= 90) makes a map read
    from a shapefile or CSV compare equal to the same map from a GeoTIFF or ISOXML.
    """
    crs = as_crs(text, what)
    code = crs.to_epsg(min_confidence=90)
    return pyproj.CRS.from_epsg(code) if code else crs


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """The WGS84 / UTM zone CRS (EPSG:326zz north, 327zz south) containing a point.

    Parameters
    ----------
    lon, lat : float
        The point, in degrees (WGS84).

    Notes
    -----
    Uses the plain 6-degree zones, without the Norway/Svalbard exceptions, so a field near a zone
    edge is mapped in the zone of its first point: any one zone is accurate to a few parts in 10^4
    across a field.
    """
    lon = float(lon)
    lat = float(lat)
    if not (np.isfinite(lon) and np.isfinite(lat) and -180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
        raise MapError(f"utm_crs_for: lon={lon!r}, lat={lat!r} is not a WGS84 position in degrees")
    zone = min(int((lon + 180.0) // 6.0) + 1, 60)
    return pyproj.CRS.from_epsg((32600 if lat >= 0.0 else 32700) + zone)


def metres_per_unit(crs: pyproj.CRS) -> float | None:
    """Metres per unit of a projected CRS's x axis, or None for a geographic (degree) CRS."""
    if crs.is_geographic:
        return None
    return float(crs.axis_info[0].unit_conversion_factor)


def crs_label(crs: pyproj.CRS) -> str:
    """A short name for a CRS: ``"EPSG:32632"`` when it has one, else its WKT."""
    auth = crs.to_authority(min_confidence=90)
    return f"{auth[0]}:{auth[1]}" if auth else crs.to_wkt()
