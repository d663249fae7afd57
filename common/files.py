"""Bounded input: every file vrsim reads is a regular file under a byte cap, checked before parsing.

A FIFO, a device (``/dev/zero`` under a ``.geojson`` name), a folder where a file is expected, a file
larger than the cap of its format, a zip archive whose members would inflate past their caps (or that
lists absurdly many members) and a grid whose arrays would not fit in memory are refused at once with
the caller's error class, naming the file and the limit, never the file's content.

Files are opened with ``O_NONBLOCK`` and checked with ``fstat`` on the open descriptor, so a FIFO never
blocks and the file checked is the file read. Libraries that open files by name themselves (GDAL,
pyshp) get the path checked first, and the files they may open beside it (``x.tif.aux.xml``, ...) too.

The caps (`BYTE_CAPS`, bytes per format) are generous for real farm files; `set_byte_caps` raises them
for the whole process (a command-line flag), ``limit=`` for one call.
"""

from __future__ import annotations

import errno
import os
import stat
import struct
from xml.etree.ElementTree import ParseError

from defusedxml import DefusedXmlException
from defusedxml import ElementTree as DET

from vrsim.common.errors import VrsimError

MiB = 1 << 20
GiB = 1 << 30

BYTE_CAPS: dict[str, int] = {
    "geotiff": 1 * GiB,  # GDAL reads rasters lazily; the grid-cell cap bounds the array
    "shapefile": 256 * MiB,  # .shp, .dbf, .shx: read whole into memory
    "geojson": 64 * MiB,  # parsed whole: Python objects take ~10x the text
    "csv": 64 * MiB,
    "xml": 64 * MiB,  # ISOXML TASKDATA.XML, GDAL .aux.xml
    "binary": 1 * GiB,  # ISOXML grid .BIN: its size must match the declared grid anyway
    "zip": 1 * GiB,  # the archive; its members count against their own formats' caps
    "prj": 1 * MiB,  # WKT of a CRS
    "toml": 1 * MiB,  # scenario files
    "geopackage": 1 * GiB,  # SQLite: GDAL reads the rows it needs
}
KIND_BY_EXTENSION = {
    ".tif": "geotiff", ".tiff": "geotiff", ".gtiff": "geotiff",
    ".shp": "shapefile", ".dbf": "shapefile", ".shx": "shapefile", ".cpg": "prj", ".prj": "prj",
    ".geojson": "geojson", ".json": "geojson", ".csv": "csv", ".xml": "xml", ".bin": "binary",
    ".zip": "zip", ".toml": "toml", ".gpkg": "geopackage",
    ".kmz": "zip", ".kml": "xml",  # a KMZ is a zip holding a KML: capped as the zip it is
}
SIDECARS_READ_WHOLE = ("xml", "prj")  # formats of side files a library parses whole when it opens them
MAX_ZIP_MEMBERS = 10_000  # an ISOXML TASKDATA or a zipped shapefile holds a handful
MAX_GRID_BYTES = 4 * GiB  # memory the arrays of one grid may take (estimate, before allocating)


def set_byte_caps(**caps: int) -> None:
    """Set caps for the whole process (``geotiff=2 * GiB``, ...); unknown formats are refused."""
    unknown = sorted(set(caps) - set(BYTE_CAPS))
    if unknown:
        raise VrsimError(f"byte cap for unknown format {unknown[0]!r} (formats: {', '.join(BYTE_CAPS)})")
    for kind, value in caps.items():
        if not isinstance(value, int) or value <= 0:
            raise VrsimError(f"byte cap {kind}={value!r}: must be a positive number of bytes")
    BYTE_CAPS.update(caps)


def _kind_of(path: str, default: str | None = None) -> str | None:
    """The format (a `BYTE_CAPS` key) of a file, by its extension (``.aux.xml`` is xml)."""
    return KIND_BY_EXTENSION.get(os.path.splitext(path)[1].lower(), default)


def cap_for(kind: str | None, limit: int | None = None) -> int:
    if limit is not None:
        return limit
    return BYTE_CAPS.get(kind or "", min(BYTE_CAPS.values()))


def _mb(n: int) -> str:
    return f"{n / MiB:,.0f} MB" if n >= MiB else f"{n:,} bytes"


def _too_large(path: str, size: int, kind: str | None, cap: int, error) -> VrsimError:
    return error(f"{path}: {size:,} bytes is over the {_mb(cap)} cap for {kind or 'such'} files "
                 "(raise it with --max-input-mb, or common.files.set_byte_caps, if the file is real)")


def _check_stat(path: str, st: os.stat_result, kind: str | None, cap: int, error) -> int:
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, expected a file")
    if not stat.S_ISREG(st.st_mode):
        what = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a file")
        raise error(f"{path}: is {what}, not a regular file; vrsim reads regular files only")
    if st.st_size > cap:
        raise _too_large(path, st.st_size, kind, cap, error)
    return st.st_size


def _open(path: str, error) -> int:
    """A read-only descriptor that never blocks on a FIFO (O_NONBLOCK), cleared again for reading."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except OSError as exc:
        raise error(f"{path}: cannot open: {exc.strerror}") from None
    return fd


def check_file(path: str, kind: str | None = None, error=VrsimError, limit: int | None = None) -> int:
    """Refuse anything but a regular file within the cap of its format; returns its size in bytes.

    Parameters
    ----------
    path : str
        The file (symlinks are followed: the target is what is checked).
    kind : str, optional
        Its format, a `BYTE_CAPS` key; default: by extension (`_kind_of`).
    error : type
        The `VrsimError` subclass to raise (MapError, VehicleError, ...).
    limit : int, optional
        A cap in bytes for this call instead of the format's.
    """
    kind = kind or _kind_of(path)
    fd = _open(path, error)
    try:
        return _check_stat(path, os.fstat(fd), kind, cap_for(kind, limit), error)
    finally:
        os.close(fd)


def read_bytes(path: str, kind: str | None = None, error=VrsimError, limit: int | None = None) -> bytes:
    """The whole file, checked as `check_file` checks it and never read past the cap (a file that
    grows while being read is refused too)."""
    kind = kind or _kind_of(path)
    cap = cap_for(kind, limit)
    fd = _open(path, error)
    try:
        _check_stat(path, os.fstat(fd), kind, cap, error)
        os.set_blocking(fd, True)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(cap + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(data) > cap:
        raise _too_large(path, len(data), kind, cap, error)
    return data


def open_text(path: str, kind: str | None = None, error=VrsimError, encoding: str = "utf-8"):
    """A text file object on `path`, checked as `check_file` checks it, for a reader that reads it
    line by line and stops at its own cap (never the whole file first). Decoding errors surface as
    `UnicodeDecodeError` while reading."""
    kind = kind or _kind_of(path)
    fd = _open(path, error)
    try:
        _check_stat(path, os.fstat(fd), kind, cap_for(kind), error)
        os.set_blocking(fd, True)
        return os.fdopen(fd, "r", encoding=encoding)
    except BaseException:
        os.close(fd)
        raise


def check_siblings(path: str, error=VrsimError) -> None:
    """Check the files a library may open beside ``path`` (GDAL's ``x.tif.aux.xml``, ``x.tfw``,
    ``x_rpc.txt``; a shapefile's ``.dbf``/``.shx``/``.prj``): every entry of the folder named ``x.*`` or
    ``x_rpc.txt`` is a folder or a regular file (a FIFO ``x.tif.aux.xml`` would hang GDAL), and the
    ones parsed whole (XML, ``.prj``) are within their caps."""
    folder = os.path.dirname(os.path.abspath(path))
    stem = os.path.splitext(os.path.basename(path))[0].lower()
    try:
        names = os.listdir(folder)
        main = os.stat(path)
    except OSError as exc:
        raise error(f"{path}: cannot read its folder: {exc.strerror}") from None
    for name in names:
        if not (name.lower().startswith(stem + ".") or name.lower() == stem + "_rpc.txt"):
            continue
        sibling = os.path.join(folder, name)
        try:
            st = os.stat(sibling)
        except OSError as exc:
            if exc.errno in (errno.ENOENT, errno.ELOOP):  # a dangling link: no library will read it
                continue
            raise error(f"{sibling}: cannot stat: {exc.strerror}") from None
        if stat.S_ISDIR(st.st_mode) or (st.st_dev, st.st_ino) == (main.st_dev, main.st_ino):
            continue
        kind = _kind_of(sibling)
        _check_stat(sibling, st, kind, cap_for(kind) if kind in SIDECARS_READ_WHOLE else float("inf"), error)


# -------------------------------------------------------------------------------------- confinement
def _inside(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def check_within(path: str, root: str, error=VrsimError, private: tuple[str, ...] = (),
                 label: str | None = None) -> str:
    """Refuse ``path`` unless it lies under ``root`` and outside every ``private`` folder, symlinks
    resolved, before anything opens it; returns the resolved path.

    What a reader may open along with it is checked too: a folder's entries (and those of its
    ``TASKDATA`` subfolder, as an ISOXML reader looks there; for a ``TASKDATA.XML``, its folder's),
    and a file's siblings ``x.*`` (a shapefile's ``.dbf``, GDAL's ``.aux.xml``) beside the path as
    given and beside its resolved target; a raster's side files that would lead GDAL to another file
    are refused (`_refuse_raster_sidecar`). The message names the path as given (``label``) and
    says nothing of whether it exists or what it holds.
    """
    label = label or path
    root = os.path.realpath(root)
    hidden = tuple(os.path.realpath(p) for p in private)

    def refuse_outside(candidate: str) -> str:
        real = os.path.realpath(candidate)
        if not _inside(real, root) or any(_inside(real, h) for h in hidden):
            raise error(f"{label}: outside the data root {root} (or in its private state folder); "
                        "refused without reading it")
        return real

    real = refuse_outside(path)
    if os.path.isdir(real):
        folders = [real] + [os.path.join(real, n) for n in folder_names(real) if n.upper() == "TASKDATA"]
        for folder in folders:
            for name in folder_names(folder):
                refuse_outside(os.path.join(folder, name))
        return real
    # A reader opens siblings beside the name it was given (pyshp, GDAL), not beside the link's target;
    # an ISOXML reader given TASKDATA.XML opens the grid and log files its folder holds.
    given = os.path.abspath(path)
    near = _siblings if _kind_of(real) != "xml" else lambda p: _names_in(os.path.dirname(p))
    for sibling in {*near(given), *near(real)}:
        refuse_outside(sibling)
        if _kind_of(real) == "geotiff":
            _refuse_raster_sidecar(sibling, label, error)
    return real


def _siblings(path: str) -> list[str]:
    """The entries beside ``path`` named ``x.*`` or ``x_rpc.txt`` (GDAL's and pyshp's side files)."""
    folder, stem = os.path.dirname(path), os.path.splitext(os.path.basename(path))[0].lower()
    return [os.path.join(folder, name) for name in folder_names(folder)
            if name.lower().startswith(stem + ".") or name.lower() == stem + "_rpc.txt"]


TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")  # classic and BigTIFF, both byte orders
# What in a GDAL ``.aux.xml`` (or HFA ``.aux``) makes GDAL open another file: external overviews, a
# dependent file, a VRT-like source.
_SIDECAR_REFERENCES = (b"overview_file", b"sourcefilename", b"dependentfile", b"/vsi")


def _refuse_raster_sidecar(sibling: str, label: str, error) -> None:
    """Refuse a raster from the data root whose side files would send GDAL to another file: external
    overviews or masks (``.ovr``, ``.msk``) that are not TIFFs, and an ``.aux.xml``/``.aux`` naming a
    file. vrsim's readers never open side files (`GDAL_READ_ENV`); this says so rather than ignoring
    them, as they were written to lead somewhere."""
    lower = sibling.lower()
    if os.path.isdir(sibling) or not lower.endswith((".ovr", ".msk", ".aux.xml", ".aux")):
        return
    if lower.endswith((".ovr", ".msk")):
        if head_bytes(sibling, 4, error) not in TIFF_SIGNATURES:
            raise error(f"{label}: its side file {os.path.basename(sibling)} (external overviews or mask) is "
                        "not a TIFF; refused without reading it")
        return
    data = read_bytes(sibling, "xml", error)
    text = data.lower() if lower.endswith(".aux") else _xml_words(data, sibling, label, error)
    if any(ref in text for ref in _SIDECAR_REFERENCES):
        raise error(f"{label}: its side file {os.path.basename(sibling)} names another file (external "
                    "overviews or a source); refused without reading it")


def _xml_words(data: bytes, sibling: str, label: str, error) -> bytes:
    """Every tag, attribute and text of an ``.aux.xml`` as parsed, lower case, one per line: what GDAL
    reads, character references decoded (``OVERVIEW&#95;FILE`` is ``overview_file``). One that does
    not parse, or declares entities, is refused: GDAL's own parser might read it otherwise."""
    import defusedxml.ElementTree as DET
    from defusedxml import DefusedXmlException

    try:
        root = DET.fromstring(data)
    except (DefusedXmlException, DET.ParseError):
        raise error(f"{label}: its side file {os.path.basename(sibling)} is not plain well-formed XML; "
                    "refused without reading it") from None
    words = [w for el in root.iter() for w in (el.tag, el.text, el.tail, *el.attrib.keys(),
                                                  *el.attrib.values()) if w]
    return "\n".join(words).lower().encode("utf-8", "replace")


def head_bytes(path: str, n: int, error=VrsimError) -> bytes:
    """The first ``n`` bytes of a regular file (checked as `check_file` checks it), to tell its format
    by its signature before a library guesses it."""
    fd = _open(path, error)
    try:
        _check_stat(path, os.fstat(fd), None, float("inf"), error)
        os.set_blocking(fd, True)
        return os.pread(fd, n, 0)
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror}") from None
    finally:
        os.close(fd)


# ------------------------------------------------------------------------------------------- GDAL
# GDAL opens more than the file it is given: side files it finds by listing the folder (.aux.xml,
# .ovr, .msk, world files), any file or URL a VRT names, the network behind /vsicurl/. vrsim reads
# only the file itself, through a named driver (rasterio's ``driver=``; pyogrio cannot restrict the
# driver, so the vector readers check the file's signature first).
GDAL_READ_ENV = {
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",  # no folder listing: no side file is found
    "GDAL_PAM_ENABLED": "NO",  # nor an .aux.xml opened by name
    "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".vrsim-reads-no-url",  # /vsicurl/ finds no file it may fetch
    "GDAL_HTTP_MAX_RETRY": "0",
    "GDAL_HTTP_TIMEOUT": "1",
    "GDAL_HTTP_CONNECTTIMEOUT": "1",
    "GDAL_VRT_ENABLE_PYTHON": "NO",
}


def gdal_path(path: str, error=VrsimError) -> str:
    """The path to give GDAL for a local file: absolute with symlinks resolved, so that no prefix in
    it (``/vsicurl/``, ``GTIFF_DIR:``, a URL) means anything to GDAL. A path naming a GDAL virtual
    file system (``/vsi...``) is refused: vrsim builds ``/vsizip/`` paths itself, from checked zips."""
    refuse_vsi(path, error)
    real = os.path.realpath(path)
    refuse_vsi(real, error, label=path)  # a symlink to /vsicurl/... would be followed by GDAL
    return real


def refuse_vsi(path: str, error=VrsimError, label: str | None = None) -> None:
    """Refuse a path naming a GDAL virtual file system (``/vsicurl/``, ``/vsizip/``, ...)."""
    if path.lower().startswith("/vsi"):
        raise error(f"{label or path}: a GDAL virtual file system path (/vsi...); vrsim reads local "
                    "files only")


def _names_in(folder: str) -> list[str]:
    return [os.path.join(folder, name) for name in folder_names(folder)]


def folder_names(folder: str) -> list[str]:
    """The names in `folder` (`os.listdir`); none when it cannot be listed (gone, not a folder, no
    permission)."""
    try:
        return os.listdir(folder)
    except OSError:
        return []


def parse_xml(data: bytes, label: str, error=VrsimError):
    """Parse untrusted XML bytes into an ElementTree element, safely: defusedxml refuses entity
    declarations and external references (the billion laughs, XXE). Raises `error` with one line
    starting ``"{label}: "`` for refused or ill-formed XML."""
    try:
        return DET.fromstring(data)
    except DefusedXmlException as exc:
        raise error(f"{label}: refused: {exc} (entity and external references are not allowed)") from None
    except ParseError as exc:
        raise error(f"{label}: not well-formed XML: {exc}") from None


# What a reader may quote from a file in an error message (a header, a cell value, a root tag). A
# service that reads files named by others over the bus turns this off: then messages name the file
# and the place in it, never what it holds.
_SHOW_CONTENT = [True]


def show_content(on: bool) -> None:
    """Let readers quote file content in error messages (the default) or not (`vrsim serve`)."""
    _SHOW_CONTENT[0] = bool(on)


def shown(value, limit: int = 60) -> str:
    """``repr(value)`` shortened to ``limit`` characters for an error message, or ``(not shown)`` when
    `show_content` is off."""
    if not _SHOW_CONTENT[0]:
        return "(not shown)"
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


# -------------------------------------------------------------------------------------- zip archives
_EOCD = b"PK\x05\x06"
_ZIP64_LOCATOR = b"PK\x06\x07"


def _zip_members(path: str, error=VrsimError) -> int:
    """The member count a zip archive declares, read from its end record before anything else
    parses it (a central directory of millions of entries would take gigabytes as ZipInfo objects)."""
    fd = _open(path, error)
    try:
        size = _check_stat(path, os.fstat(fd), "zip", cap_for("zip"), error)
        os.set_blocking(fd, True)
        tail_len = min(size, 22 + 0xFFFF)
        tail = os.pread(fd, tail_len, size - tail_len)
        at = tail.rfind(_EOCD)
        if at < 0 or at + 22 > len(tail):
            raise error(f"{path}: not a zip archive (no end-of-central-directory record)")
        count = struct.unpack_from("<H", tail, at + 10)[0]
        if count == 0xFFFF and at >= 20 and tail[at - 20:at - 16] == _ZIP64_LOCATOR:
            (offset,) = struct.unpack_from("<Q", tail, at - 20 + 8)
            record = os.pread(fd, 56, offset)
            if len(record) < 56 or record[:4] != b"PK\x06\x06":
                raise error(f"{path}: damaged zip64 end record")
            count = struct.unpack_from("<Q", record, 32)[0]
    finally:
        os.close(fd)
    if count > MAX_ZIP_MEMBERS:
        raise error(f"{path}: the zip archive lists {count:,} members, more than the "
                    f"{MAX_ZIP_MEMBERS:,} vrsim opens")
    return count


def open_zip(path: str, error=VrsimError):
    """A `zipfile.ZipFile` whose members were checked: at most `MAX_ZIP_MEMBERS`, each member's declared
    uncompressed size within its format's cap and the sum within the zip cap, all before anything is
    inflated (zipfile never inflates a member past its declared size)."""
    import zipfile

    _zip_members(path, error)
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise error(f"{path}: not a readable zip archive: {exc}") from None
    total = 0
    for info in archive.infolist():
        if info.is_dir():
            continue
        kind = _kind_of(info.filename)
        cap = cap_for(kind)
        if info.file_size > cap:
            archive.close()
            raise _too_large(f"{path}: member {info.filename}", info.file_size, kind, cap, error)
        total += info.file_size
    if total > cap_for("zip"):
        archive.close()
        raise _too_large(f"{path}: members together", total, "zip", cap_for("zip"), error)
    return archive


def read_member(archive, name: str, path: str, error=VrsimError, limit: int | None = None) -> bytes:
    """One member of an archive from `open_zip`, never inflated past its cap."""
    import zipfile

    kind = _kind_of(name)
    cap = cap_for(kind, limit)
    try:
        with archive.open(name) as fh:
            data = fh.read(cap + 1)
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        raise error(f"{path}: cannot read member {name}: {exc}") from None
    if len(data) > cap:
        raise _too_large(f"{path}: member {name}", len(data), kind, cap, error)
    return data


# -------------------------------------------------------------------------------------- grid memory
def _available_memory_bytes(meminfo: str = "/proc/meminfo") -> int | None:
    """``MemAvailable`` of the machine (Linux), None where it cannot be read."""
    try:
        with open(meminfo, "rb") as fh:
            for line in fh.read(1 << 16).splitlines():
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_grid_memory(rows: int, cols: int, bytes_per_cell: int, where: str, error=VrsimError,
                      max_bytes: int | None = None) -> None:
    """Refuse a grid whose arrays (``bytes_per_cell`` over all of them) would exceed `MAX_GRID_BYTES`
    (or ``max_bytes``) or the memory available right now, before allocating anything."""
    check_memory(rows * cols * bytes_per_cell, f"a grid of {rows:,} rows x {cols:,} columns "
                 f"({bytes_per_cell} bytes per cell)", where, error, max_bytes)


def check_memory(need_bytes: float, what: str, where: str, error=VrsimError,
                 max_bytes: int | None = None) -> None:
    """Refuse ``what`` when the ``need_bytes`` it would allocate exceed `MAX_GRID_BYTES` (or
    ``max_bytes``) or the memory available right now."""
    cap = MAX_GRID_BYTES if max_bytes is None else max_bytes
    if need_bytes > cap:
        raise error(f"{where}: {what} needs about {need_bytes / GiB:,.1f} GB, over the "
                    f"{cap / GiB:,.1f} GB cap")
    available = _available_memory_bytes()
    if available is not None and need_bytes > available:
        raise error(f"{where}: {what} needs about {need_bytes / GiB:,.1f} GB, more than the "
                    f"{available / GiB:,.1f} GB of memory available")
