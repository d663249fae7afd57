"""Vector files read through pyogrio (GDAL/OGR) only as what they claim to be.

GDAL picks the driver of a file by its content, and some drivers open other files or URLs named
inside it (an OGR VRT, a CSV with a ``.csvt``, ...). pyogrio cannot restrict the drivers it opens with
(its ``read`` takes no ``driver``; https://github.com/geopandas/pyogrio/issues/310), so the file's
signature is checked first: a ``.shp`` must start with the shapefile file code, a ``.gpkg`` with
SQLite's header and a GeoPackage application id, a ``.zip`` must hold such a ``.shp``, which vrsim then
names inside the checked archive itself (``/vsizip/<resolved zip>/<member>``). Only the named driver
(``DRIVERS``) recognizes such a file. No side-file scan, no network (`common.files.GDAL_READ_ENV`).
"""

from __future__ import annotations

import os
import posixpath
import zipfile

from common import MapError, files

# Extension -> the GDAL driver that reads it.
DRIVERS = {".shp": "ESRI Shapefile", ".gpkg": "GPKG", ".zip": "ESRI Shapefile"}
SHAPEFILE_CODE = b"\x00\x00\x27\x0a"  # 9994, big-endian, the first 4 bytes of every .shp
SQLITE_HEADER = b"SQLite format 3\x00"
GPKG_IDS = (b"GPKG", b"GP10", b"GP11")  # application_id at byte 68 (GeoPackage 1.2+, 1.0, 1.1)


def read_vector(path: str):
    """``pyogrio.raw.read`` of a ``.shp``, ``.gpkg`` or zipped shapefile, its signature checked first.

    Returns
    -------
    tuple
        What ``pyogrio.raw.read`` returns: (meta, fids, geometry as WKB, field columns).

    Raises
    ------
    MapError
        A ``/vsi`` path, another extension, a file that is not what its extension says, or a file
        GDAL cannot read (one line naming the file).
    """
    import pyogrio
    from pyogrio.errors import DataLayerError, DataSourceError

    source, driver = _gdal_source(path)
    pyogrio.set_gdal_config_options(files.GDAL_READ_ENV)  # process-wide: pyogrio has no scoped Env
    try:
        return pyogrio.raw.read(source)
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise MapError(f"{path}: cannot read as a vector file ({driver}): {exc}") from None


def _gdal_source(path: str) -> tuple[str, str]:
    """The path to give GDAL for ``path`` and the driver its content was checked for."""
    real = files.gdal_path(path, MapError)
    ext = os.path.splitext(path)[1].lower()
    if ext not in DRIVERS:
        raise MapError(f"{path}: vrsim reads vector files as .shp, .gpkg or a .zip holding a .shp")
    if ext == ".zip":
        return f"/vsizip/{real}/{_zipped_shapefile(path)}", DRIVERS[ext]
    head = files.head_bytes(path, 100, MapError)
    if ext == ".shp" and not head.startswith(SHAPEFILE_CODE):
        raise MapError(f"{path}: cannot read as a vector file: not a shapefile (no shapefile header)")
    if ext == ".gpkg" and not (head.startswith(SQLITE_HEADER) and head[68:72] in GPKG_IDS):
        raise MapError(f"{path}: cannot read as a vector file: not a GeoPackage (no SQLite header with a "
                       "GeoPackage application id)")
    return real, DRIVERS[ext]


def _zipped_shapefile(path: str) -> str:
    """The first ``.shp`` member of a checked zip archive, itself checked to be a shapefile."""
    with files.open_zip(path, MapError) as archive:
        shps = [n for n in archive.namelist() if n.lower().endswith(".shp") and not n.startswith("__MACOSX")]
        if not shps:
            raise MapError(f"{path}: the zip archive holds no .shp file")
        name = shps[0]
        parts = name.replace("\\", "/").split("/")
        if name.startswith("/") or ".." in parts or posixpath.normpath(name) != name:
            raise MapError(f"{path}: member {name!r} is not a plain path inside the archive")
        try:
            with archive.open(name) as fh:
                head = fh.read(4)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
            raise MapError(f"{path}: cannot read member {name}: {exc}") from None
    if head != SHAPEFILE_CODE:
        raise MapError(f"{path}: cannot read as a vector file: member {name} is not a shapefile")
    return name
