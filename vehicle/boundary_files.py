"""Field boundaries as terminals and Google Earth keep them: KML/KMZ and the ISOXML partfield.

* KML (``.kml``) or KMZ (``.kmz``, a zip holding one ``.kml``): the ``Polygon`` of the document (of
  one placemark), its ``outerBoundaryIs`` ring and its ``innerBoundaryIs`` rings (holes),
  ``lon,lat[,alt]`` in WGS84.
* ISOXML TASKDATA (a folder, its ``TASKDATA.XML`` or a ``.zip`` holding one): the partfield (``PFD``)
  boundary, a ``PLN`` of type 1 whose line strings (``LSG``) are the exterior ring (type 1) and the
  interior rings (type 2), points ``PNT`` C (north, latitude) and D (east, longitude) in WGS84. An
  ISOXML ring may leave its closing point out (the standard's polygon closes itself); a KML ring
  must repeat its first point (the KML standard), and one that does not is refused.

The files are untrusted: parsed with defusedxml (no entities, no external references), read through
`common.files` (regular files under their byte caps, zip members checked before they are inflated).
"""

from __future__ import annotations

import os
import posixpath

import numpy as np
from shapely.geometry import MultiPolygon, Polygon

from vrsim.common import files
from vrsim.common.errors import VehicleError

PLN_BOUNDARY = "1"  # PLN A: partfield boundary
LSG_EXTERIOR, LSG_INTERIOR = "1", "2"  # LSG A: polygon exterior / interior


def read_kml(path: str, placemark: str | None = None):
    """The polygon (holes included) of a ``.kml`` or ``.kmz``, in WGS84 degrees.

    A document whose polygons lie in several placemarks is refused, listing their names, unless
    `placemark` names one; a placemark of several polygons (a MultiGeometry) gives a MultiPolygon.
    """
    root = files.parse_xml(_kml_bytes(path), f"field file {path}", VehicleError)
    marks = [el for el in root.iter() if _local(el.tag) == "Placemark"] or [root]
    found = [(_kml_name(mark), [el for el in mark.iter() if _local(el.tag) == "Polygon"]) for mark in marks]
    found = [(name, polygons) for name, polygons in found if polygons]
    if not found:
        raise VehicleError(f"field file {path}: no Polygon in the KML (a boundary must be a polygon, not "
                           "a point or a line)")
    listed = ", ".join(repr(name) for name, _ in found)
    if placemark is not None:
        found = [(name, polygons) for name, polygons in found if name == placemark]
        if not found:
            raise VehicleError(f"field file {path}: no placemark {placemark!r} with a polygon; placemarks: "
                               f"{listed}")
    if len(found) > 1:
        raise VehicleError(f"field file {path}: {len(found)} placemarks have polygons: {listed}; a boundary "
                           "is one (keep one in the file)")
    polygons = [_kml_polygon(polygon, path) for polygon in found[0][1]]
    return polygons[0] if len(polygons) == 1 else MultiPolygon(polygons)


def _kml_name(mark) -> str:
    return next(((c.text or "").strip() for c in mark if _local(c.tag) == "name"), "")


def _kml_polygon(polygon, path: str) -> Polygon:
    outer = [_kml_ring(el, path) for el in _children(polygon, "outerBoundaryIs")]
    if len(outer) != 1:
        raise VehicleError(f"field file {path}: the Polygon has {len(outer)} outerBoundaryIs rings; it "
                           "needs one")
    inner = [_kml_ring(el, path) for el in _children(polygon, "innerBoundaryIs")]
    return Polygon(outer[0], inner)


def read_partfield(path: str, partfield: str | None = None) -> Polygon:
    """The partfield boundary (exterior and interior rings) of a TASKDATA, in WGS84 degrees.

    `partfield` (a ``PFD`` id such as ``PFD2``, or its designator) chooses among several partfields
    with a boundary; without it such a TASKDATA is refused, listing them.
    """
    root = files.parse_xml(_taskdata_bytes(path), f"field file {path}", VehicleError)
    if _local(root.tag) != "ISO11783_TaskData":
        raise VehicleError(f"field file {path}: root element is {files.shown(root.tag)}, not "
                           "<ISO11783_TaskData>")
    found = [(pfd, [p for p in pfd.findall("PLN") if p.get("A") == PLN_BOUNDARY]) for pfd in root.iter("PFD")]
    found = [(pfd, plns) for pfd, plns in found if plns]
    listed = ", ".join(f"{pfd.get('A')} {pfd.get('C') or ''!r}" for pfd, _ in found)
    if partfield is not None:
        found = [(pfd, plns) for pfd, plns in found if partfield in (pfd.get("A"), pfd.get("C"))]
        if not found:
            raise VehicleError(f"field file {path}: no partfield {partfield!r} with a boundary; "
                               f"partfields: {listed or 'none'}")
    if not found:
        raise VehicleError(f"field file {path}: no partfield (PFD) has a boundary (PLN A=1)")
    if len(found) > 1:
        raise VehicleError(f"field file {path}: {len(found)} partfields have a boundary: {listed}; name one")
    pfd, plns = found[0]
    if len(plns) > 1:
        raise VehicleError(f"field file {path}: partfield {pfd.get('A')} has {len(plns)} boundary polygons; "
                           "give one")
    where = f"field file {path}: partfield {pfd.get('A')}"
    lsgs = plns[0].findall("LSG")
    outer = [_pln_ring(lsg, where) for lsg in lsgs if lsg.get("A") == LSG_EXTERIOR]
    inner = [_pln_ring(lsg, where) for lsg in lsgs if lsg.get("A") == LSG_INTERIOR]
    if len(outer) != 1:
        raise VehicleError(f"{where}: its boundary has {len(outer)} exterior rings (LSG A=1); it needs one")
    return Polygon(outer[0], inner)


def is_taskdata(path: str) -> bool:
    """A TASKDATA given as a boundary: a folder, ``TASKDATA.XML`` or a zip holding one."""
    if os.path.isdir(path) or os.path.basename(path).upper() == "TASKDATA.XML":
        return True
    if path.lower().endswith(".zip"):
        with files.open_zip(path, VehicleError) as z:
            return any(posixpath.basename(n).upper() == "TASKDATA.XML" for n in z.namelist())
    return False


def _local(tag) -> str:
    """An element's name without its namespace (KML 2.2 documents use one, older ones none)."""
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _children(el, name: str):
    """The ``LinearRing`` of each ``name`` child of `el`."""
    return [ring for child in el if _local(child.tag) == name
            for ring in child if _local(ring.tag) == "LinearRing"]


def _kml_ring(ring, path: str) -> np.ndarray:
    """A LinearRing's ``coordinates`` as (k, 2) lon/lat, closed as KML requires."""
    text = next((c.text or "" for c in ring if _local(c.tag) == "coordinates"), "")
    points = []
    for token in text.split():
        parts = token.split(",")
        try:
            lon, lat = float(parts[0]), float(parts[1])
        except (ValueError, IndexError):
            raise VehicleError(f"field file {path}: coordinate {files.shown(token)} is not "
                               "lon,lat[,alt]") from None
        if not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
            raise VehicleError(f"field file {path}: coordinate {files.shown(token)} is not WGS84 degrees")
        points.append((lon, lat))
    xy = np.array(points, dtype=float).reshape(-1, 2)
    if len(xy) < 4:
        raise VehicleError(f"field file {path}: a ring of {len(xy)} points; a closed ring needs at least 4")
    if not np.array_equal(xy[0], xy[-1]):
        raise VehicleError(f"field file {path}: the ring does not close: it starts at "
                           f"{tuple(xy[0].tolist())} and ends at {tuple(xy[-1].tolist())} (KML repeats "
                           "the first point last)")
    return xy


def _pln_ring(lsg, where: str) -> np.ndarray:
    """An LSG's points as (k, 2) lon/lat (PNT D east, C north)."""
    points = []
    for i, pnt in enumerate(lsg.findall("PNT")):
        try:
            lat, lon = float(pnt.get("C")), float(pnt.get("D"))
        except (TypeError, ValueError):
            raise VehicleError(f"{where}: point {i}: C={files.shown(pnt.get('C'))}, "
                               f"D={files.shown(pnt.get('D'))} is not a latitude and longitude") from None
        if not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
            raise VehicleError(f"{where}: point {i}: C={lat!r}, D={lon!r} is not WGS84 degrees")
        points.append((lon, lat))
    if len(points) < 3:
        raise VehicleError(f"{where}: a ring (LSG A={lsg.get('A')}) of {len(points)} points; a polygon "
                           "needs 3")
    return np.array(points, dtype=float)


def _kml_bytes(path: str) -> bytes:
    if not path.lower().endswith(".kmz"):
        return files.read_bytes(path, "xml", VehicleError)
    with files.open_zip(path, VehicleError) as z:
        kmls = [n for n in z.namelist() if n.lower().endswith(".kml") and not n.startswith("__MACOSX")]
        if not kmls:
            raise VehicleError(f"field file {path}: the KMZ holds no .kml")
        name = next((n for n in kmls if posixpath.basename(n).lower() == "doc.kml"), kmls[0])  # KMZ's main
        return files.read_member(z, name, path, VehicleError, limit=files.cap_for("xml"))


def _taskdata_bytes(path: str) -> bytes:
    if os.path.isdir(path):
        for folder in (path, os.path.join(path, "TASKDATA")):
            names = [n for n in os.listdir(folder) if n.upper() == "TASKDATA.XML"] \
                if os.path.isdir(folder) else []
            if names:
                return files.read_bytes(os.path.join(folder, names[0]), "xml", VehicleError)
        raise VehicleError(f"field file {path}: the folder holds no TASKDATA.XML")
    if path.lower().endswith(".zip"):
        with files.open_zip(path, VehicleError) as z:
            names = sorted((n for n in z.namelist() if posixpath.basename(n).upper() == "TASKDATA.XML"),
                           key=len)  # the shallowest one
            return files.read_member(z, names[0], path, VehicleError)
    return files.read_bytes(path, "xml", VehicleError)
