"""A scenario uploaded from the page with its files: checked, and kept in a folder of its own under the
data root, where the services read it as any scenario from the bus (`services.bus.dataroot`).

An upload is the scenario's TOML file with the files it names (field boundary, prescription map, a
shapefile's ``.shx``, ``.dbf``, ``.prj`` beside its ``.shp``, ...), or one ``.zip`` of them (its folder
layout kept). What is refused, before anything is kept: a name with a path or characters other than
letters, digits, ``.``, ``_`` and ``-`` (a zip member: such names, in folders), a file of a kind no
reader of vrsim opens, a file over its format's byte cap (`common.files.BYTE_CAPS`) or an upload over
`MAX_UPLOAD_BYTES` in all, more than `MAX_FILES` files, no scenario or several, a scenario that does
not parse, names a file outside the upload's folder, or names one that is not in the upload (the
message names the table, the key and the file to add). The folder is written whole or not at all
(a hidden temporary folder renamed into place); the `KEEP_UPLOADS` newest are kept.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass

from vrsim.common import ScenarioError, VrsimError, files

UPLOADS_FOLDER = os.path.join("runs", "uploads")  # under the data root
MAX_UPLOAD_BYTES = 256 * files.MiB  # a request's body, counted as it comes
MAX_FILES = 64  # files in one upload (in its zip too)
MAX_UNPACKED_BYTES = 512 * files.MiB  # an uploaded zip's members together, as they declare (and are read)
KEEP_UPLOADS = 16  # upload folders kept (a run's report rebuilds its world from its files)
NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")
ALLOWED_KINDS = ("geotiff", "shapefile", "geojson", "csv", "xml", "binary", "zip", "prj", "toml",
                 "geopackage")
_COPY_BYTES = 1 << 20


class UploadError(ScenarioError):
    """An upload refused: one line naming the file and what is wrong (a 400 or 413 on the page)."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class Upload:
    """An upload kept: its folder, its scenario's TOML text, path and folder (the ``base_dir``)."""

    folder: str
    text: str
    source: str
    base_dir: str


def save(parts: list, data_root: str) -> Upload:
    """Check ``parts`` (``(file name, binary file object)`` as the browser sent them) and keep them in a
    new folder under ``data_root``'s `UPLOADS_FOLDER`.

    Raises
    ------
    UploadError
        What is wrong, naming the file (nothing is kept then).
    """
    if not parts:
        raise UploadError("upload: no files (choose the scenario's .toml with its field and map files, or "
                          "a .zip of them)")
    if len(parts) > MAX_FILES:
        raise UploadError(f"upload: {len(parts)} files, more than the {MAX_FILES} one upload may hold")
    names = [_checked_name(name) for name, _ in parts]
    if len(set(names)) != len(names):
        raise UploadError(f"upload: the file name {_twice(names)} comes twice")
    home = os.path.join(data_root, UPLOADS_FOLDER)
    os.makedirs(home, exist_ok=True)
    partial = tempfile.mkdtemp(prefix=".partial-", dir=home)
    try:
        for name, (_, fh) in zip(names, parts, strict=True):
            _copy(fh, os.path.join(partial, name), name)
        zips = [n for n in names if n.lower().endswith(".zip")]
        if not any(n.lower().endswith(".toml") for n in names) and len(zips) == 1:
            _unpack(os.path.join(partial, zips[0]), partial, zips[0])
        scenario_path = _the_scenario(partial)
        folder = os.path.join(home, _folder_name(time.time_ns()))
        os.rename(partial, folder)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    try:
        upload = _checked_scenario(folder, os.path.join(folder, os.path.relpath(scenario_path, partial)))
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    _prune(home, keep=folder)
    return upload


def _checked_name(name) -> str:
    if not isinstance(name, str) or not NAME.match(name):
        raise UploadError(f"upload: file name {str(name)[:80]!r}: only letters, digits, '.', '_' and '-', "
                          "no folders, at most 128 characters")
    kind = files.KIND_BY_EXTENSION.get(os.path.splitext(name)[1].lower())
    if kind not in ALLOWED_KINDS:
        raise UploadError(f"upload: {name}: not a file vrsim reads (a scenario .toml, a field or map: "
                          ".geojson, .shp with .shx/.dbf/.prj, .tif, .csv, .gpkg, ISOXML .xml/.bin, .zip)")
    return name


def _twice(names: list[str]) -> str:
    seen = set()
    for name in names:
        if name in seen:
            return name
        seen.add(name)
    return ""


def _copy(fh, path: str, name: str) -> None:
    """Copy one uploaded file, within its format's byte cap."""
    kind = files.KIND_BY_EXTENSION.get(os.path.splitext(name)[1].lower())
    cap, size = files.cap_for(kind), 0
    with open(path, "xb") as out:
        while chunk := fh.read(_COPY_BYTES):
            size += len(chunk)
            if size > cap:
                raise UploadError(f"upload: {name}: over the {cap // files.MiB} MB vrsim reads of a "
                                  f"{kind} file", 413)
            out.write(chunk)


def _unpack(path: str, folder: str, name: str) -> None:
    """The members of an uploaded zip into ``folder`` (checked as `common.files.open_zip` checks a zip
    it reads; names as `_checked_name`, in folders at most 4 deep); the zip itself removed."""
    try:
        archive = files.open_zip(path, UploadError)
    except UploadError as exc:
        raise UploadError(f"upload: {str(exc).replace(path, name)}", 413 if "over" in str(exc) else 400) \
            from None
    with archive:
        members = [m for m in archive.infolist() if not m.is_dir()]
        if len(members) > MAX_FILES:
            raise UploadError(f"upload: {name}: {len(members)} files, more than the {MAX_FILES} one upload "
                              "may hold")
        unpacked = sum(m.file_size for m in members)
        if unpacked > MAX_UNPACKED_BYTES:
            raise UploadError(f"upload: {name}: {unpacked / files.MiB:.0f} MB unpacked, over the "
                              f"{MAX_UNPACKED_BYTES // files.MiB} MB an upload may hold", 413)
        for member in members:
            parts = member.filename.split("/")
            if len(parts) > 5 or any(not NAME.match(p) for p in parts[:-1]):
                raise UploadError(f"upload: {name}: member {member.filename[:120]!r}: folders of letters, "
                                  "digits, '.', '_' and '-' only, at most 4 deep, no '..'")
            _checked_name(parts[-1])
            target = os.path.join(folder, *parts)
            os.makedirs(os.path.dirname(target), exist_ok=True)
            try:
                data = files.read_member(archive, member.filename, path, UploadError)
            except UploadError as exc:
                raise UploadError(f"upload: {str(exc).replace(path, name)}") from None
            with open(target, "xb") as out:
                out.write(data)
    os.unlink(path)


def _the_scenario(folder: str) -> str:
    """The one ``.toml`` in the upload (at its top, else anywhere in an unpacked zip)."""
    found = []
    for here, dirs, names in os.walk(folder):
        dirs.sort()
        found += [os.path.join(here, n) for n in sorted(names) if n.lower().endswith(".toml")]
    top = [p for p in found if os.path.dirname(p) == folder]
    chosen = top or found
    if len(chosen) != 1:
        listed = ", ".join(os.path.relpath(p, folder) for p in chosen) or "none"
        raise UploadError(f"upload: needs exactly one scenario (.toml) besides its field and map files; "
                          f"found {listed}")
    return chosen[0]


def _checked_scenario(folder: str, path: str) -> Upload:
    """Parse the scenario as the services will; every file it names must be in the upload."""
    from vrsim.services.bus.dataroot import DataRoot
    from vrsim.services.sim import scenario

    name = os.path.relpath(path, folder)
    text = files.read_bytes(path, "toml", UploadError).decode("utf-8", "replace")
    base_dir = os.path.dirname(path)
    try:
        sc = DataRoot(folder).scenario(text, name, base_dir)
    except VrsimError as exc:
        raise UploadError(_in_upload(str(exc), folder)) from None
    for what, named in scenario.files_named(sc):
        if not os.path.lexists(named):
            given = os.path.relpath(named, base_dir)
            raise UploadError(f"upload: {name} names {what} {given}, which is not in the upload: choose it "
                              "together with the scenario (a shapefile with its .shx, .dbf and .prj), or "
                              "upload a .zip of the scenario's folder")
    return Upload(folder, text, path, base_dir)


def _in_upload(message: str, folder: str) -> str:
    """A parse error's message with the upload's folder left out (it says "the upload")."""
    message = message.replace(f"the data root {folder}", "the upload's folder")
    return "upload: " + message.replace(folder + os.sep, "").replace(folder, "the upload")


def _folder_name(now_ns: int) -> str:
    """An upload folder's name: its time to the nanosecond, so that names sort as the uploads came (a
    second's uploads too: `_prune` keeps the newest by name), and a random tail against a clash."""
    seconds, ns = divmod(now_ns, 1_000_000_000)
    return f"{time.strftime('%Y%m%dT%H%M%S', time.gmtime(seconds))}.{ns:09d}-{os.urandom(4).hex()}"


def _prune(home: str, keep: str) -> None:
    """Remove all but the `KEEP_UPLOADS` newest upload folders (and partial ones of a crashed upload)."""
    try:
        entries = sorted(e for e in os.listdir(home) if not e.startswith("."))
    except OSError:
        return
    for entry in entries[:-KEEP_UPLOADS]:
        path = os.path.join(home, entry)
        if path != keep:
            shutil.rmtree(path, ignore_errors=True)
