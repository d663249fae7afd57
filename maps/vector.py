"""Vector files read through pyogrio (GDAL/OGR) only as what they claim to be.

GDAL picks the driver of a file by its content, and some drivers open other files or URLs named
inside it (an OGR VRT, a CSV with a ``.csvt``, ...). pyogrio cannot restrict the drivers it opens with
(its ``read`` takes no ``driver``; https://github.com/geopandas/pyogrio/issues/310), so the file's
signature is checked first: a ``.shp`` must start with the shapefile file code, a ``.gpkg`` with
SQLite's header and a GeoPackage application id, a ``.zip`` must hold such a ``.shp``, which vrsim then
names inside the checked archive itself (``/vsizip/<resolved zip>/<member>``). Only the named driver
(``DRIVERS``) recognizes such a file. No side-file scan, no network (`common.files.GDAL_READ_ENV`).

A zip or folder holding several shapefiles, or a GeoPackage with several layers (an Operations Center
export holds one per product or operation), is never read by a guess: `_layers` lists them and the
caller names one (``layer=``, ``--layer``).
"""

from __future__ import annotations

import os
import posixpath
import sys
import zipfile
from dataclasses import dataclass

from vrsim.common import MapError, files

# Extension -> the GDAL driver that reads it.
DRIVERS = {".shp": "ESRI Shapefile", ".gpkg": "GPKG", ".zip": "ESRI Shapefile"}
SHAPEFILE_CODE = b"\x00\x00\x27\x0a"  # 9994, big-endian, the first 4 bytes of every .shp
SQLITE_HEADER = b"SQLite format 3\x00"
GPKG_IDS = (b"GPKG", b"GP10", b"GP11")  # application_id at byte 68 (GeoPackage 1.2+, 1.0, 1.1)


def ogr():
    """The pyogrio module, imported without its optional pandas.

    pyogrio imports pandas where it is installed (for geopandas' data frames, which vrsim does not use:
    it reads and writes through ``pyogrio.raw``, with numpy and Arrow), and pandas is some 40 MB of each
    process that opens a vector file, a quarter of `vrsim run`'s libraries. For pyogrio's import only,
    ``sys.modules`` maps pandas to None, so that its ``import pandas`` raises ImportError, which pyogrio
    takes as not installed; ``import pandas`` works as ever after it.
    """
    if "pyogrio" not in sys.modules and "pandas" not in sys.modules:
        sys.modules["pandas"] = None
        try:
            import pyogrio  # noqa: F401
        finally:
            del sys.modules["pandas"]
    import pyogrio

    return pyogrio


@dataclass(frozen=True)
class _Layer:
    """One layer of a vector file: its name (a shapefile's name without ``.shp``), record count, fields."""

    name: str
    records: int
    fields: tuple


def read_vector(path: str, layer: str | None = None):
    """``pyogrio.raw.read`` of a ``.shp``, ``.gpkg``, zipped shapefile or folder of shapefiles, its
    signature checked first.

    Parameters
    ----------
    path : str
    layer : str, optional
        The layer to read where the file holds several (see `_layers`); required then.

    Returns
    -------
    tuple
        What ``pyogrio.raw.read`` returns: (meta, fids, geometry as WKB, field columns).

    Raises
    ------
    MapError
        A ``/vsi`` path, another extension, a file that is not what its extension says, several layers
        and none (or one that does not exist) named, or a file GDAL cannot read (one line naming the
        file).
    """
    pyogrio = ogr()
    from pyogrio.errors import DataLayerError, DataSourceError

    source, driver, inner = gdal_source(path, layer)
    pyogrio.set_gdal_config_options(files.GDAL_READ_ENV)  # process-wide: pyogrio has no scoped Env
    try:
        return pyogrio.raw.read(source, layer=inner)
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise MapError(f"{path}: cannot read as a vector file ({driver}): {exc}") from None


def _layers(path: str) -> list[_Layer]:
    """Every layer of a ``.zip`` (its shapefiles), a folder (its shapefiles) or a ``.gpkg``, in name order."""
    pyogrio = ogr()
    from pyogrio.errors import DataLayerError, DataSourceError

    pyogrio.set_gdal_config_options(files.GDAL_READ_ENV)
    found = []
    for name, source, inner in _sources(path):
        try:
            info = pyogrio.read_info(source, layer=inner)
        except (DataSourceError, DataLayerError, OSError) as exc:
            raise MapError(f"{path}: cannot read layer {name!r}: {exc}") from None
        found.append(_Layer(name, int(info["features"]), tuple(str(f) for f in info["fields"])))
    return found


def _describe(found: list[_Layer]) -> str:
    """``"A (780 records; fields Time, Heading), B (...)"``: layers for a one-line message."""
    return "; ".join(f"{x.name!r} ({x.records:,} records; fields {', '.join(x.fields) or 'none'})"
                     for x in found)


def gdal_source(path: str, layer: str | None = None) -> tuple[str, str, str | None]:
    """The path to give GDAL for ``path``, the driver its content was checked for and the GeoPackage
    layer to read (None: the file's only one)."""
    sources = _sources(path)
    if layer is None and len(sources) > 1:
        raise MapError(f"{path}: holds {len(sources)} layers; name one with --layer NAME: "
                       f"{_describe(_layers(path))}")
    if layer is not None:
        chosen = [s for s in sources if s[0].lower() == layer.lower()]
        if not chosen:
            raise MapError(f"{path}: no layer {layer!r}; layers: {_describe(_layers(path))}")
        sources = chosen[:1]
    _, source, inner = sources[0]
    ext = ".shp" if os.path.isdir(path) else os.path.splitext(path)[1].lower()
    return source, DRIVERS[ext], inner


def _sources(path: str) -> list[tuple[str, str, str | None]]:
    """(layer name, GDAL path, GeoPackage layer) of every layer, each file's signature checked."""
    real = files.gdal_path(path, MapError)
    if os.path.isdir(path):
        shps = sorted(n for n in os.listdir(path) if n.lower().endswith(".shp"))
        if not shps:
            raise MapError(f"{path}: the folder holds no shapefile (.shp)")
        for name in shps:
            files.check_file(os.path.join(path, name), error=MapError)
            files.check_siblings(os.path.join(path, name), MapError)  # the .dbf, .shx, .prj GDAL opens
            _check_head(os.path.join(path, name), ".shp")
        return [(name[:-4], os.path.join(real, name), None) for name in shps]
    ext = os.path.splitext(path)[1].lower()
    if ext not in DRIVERS:
        raise MapError(f"{path}: vrsim reads vector files as .shp, .gpkg, a .zip holding a .shp or a folder "
                       "of .shp")
    if ext == ".zip":
        return [(posixpath.basename(n)[:-4], f"/vsizip/{real}/{n}", None) for n in _zipped_shapefiles(path)]
    _check_head(path, ext)
    if ext == ".gpkg":
        pyogrio = ogr()
        pyogrio.set_gdal_config_options(files.GDAL_READ_ENV)
        try:
            names = [str(n) for n, kind in pyogrio.list_layers(real) if kind is not None]  # not plain tables
        except (pyogrio.errors.DataSourceError, OSError) as exc:
            raise MapError(f"{path}: cannot read as a vector file (GPKG): {exc}") from None
        return [(n, real, n) for n in names] or [("", real, None)]
    return [(os.path.basename(path)[:-4], real, None)]


def _check_head(path: str, ext: str) -> None:
    head = files.head_bytes(path, 100, MapError)
    if ext == ".shp" and not head.startswith(SHAPEFILE_CODE):
        raise MapError(f"{path}: cannot read as a vector file: not a shapefile (no shapefile header)")
    if ext == ".gpkg" and not (head.startswith(SQLITE_HEADER) and head[68:72] in GPKG_IDS):
        raise MapError(f"{path}: cannot read as a vector file: not a GeoPackage (no SQLite header with a "
                       "GeoPackage application id)")


def _zipped_shapefiles(path: str) -> list[str]:
    """The ``.shp`` members of a checked zip archive, each checked to be a shapefile, in name order."""
    with files.open_zip(path, MapError) as archive:
        shps = sorted(n for n in archive.namelist()
                      if n.lower().endswith(".shp") and not n.startswith("__MACOSX"))
        if not shps:
            raise MapError(f"{path}: the zip archive holds no .shp file")
        for name in shps:
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
    return shps
