"""Outputs whole or absent: every file vrsim writes appears under its final name complete, or not at all.

`written` gives a writer a temporary name beside the final one and renames it when the writer is done;
`staged` does the same for a set of files that belong together (a run's folder), moving them in with a
completion mark (summary.json) last. A failure leaves no partial file under a final name, and one for
lack of space or permission becomes one line naming the folder and the cause (`write_failure`), which
the CLI prints with exit code 2.
"""

from __future__ import annotations

import errno
import logging
import os
import sys
from contextlib import contextmanager

from vrsim.common.errors import VrsimError
from vrsim.common.files import folder_names

# Causes of a failed write the user can fix (free space, a writable folder); any other is a bug.
WRITE_CAUSES = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "disk quota exceeded",
                errno.EACCES: "permission denied", errno.EPERM: "operation not permitted",
                errno.EROFS: "read-only file system", errno.EFBIG: "file too large"}
NEARLY_FULL_BYTES = 256 * 1024  # a failed write with less than this left is taken for a full disk
_TEMP_MARK = "-partial-"  # then 8 hex digits: ``.track-partial-1a2b3c4d.csv``


def write_failure(exc: BaseException, folder: str, error=VrsimError) -> VrsimError | None:
    """The one-line error for ``exc`` raised while writing into ``folder`` when its cause is space or
    permission (an `OSError` with that errno, or a library's message quoting its ``strerror``: GDAL's,
    Arrow's, an earlier `VrsimError`'s; or, whatever the message, a folder with less than
    `NEARLY_FULL_BYTES` left, read-only or not writable: SQLite under GDAL says "no such table" when
    the disk fills); None for any other cause. Call it before removing what was written."""
    texts = {os.strerror(code): cause for code, cause in WRITE_CAUSES.items()}
    seen, cause = exc, None
    while seen is not None and cause is None:
        if isinstance(seen, OSError) and seen.errno in WRITE_CAUSES:
            cause = WRITE_CAUSES[seen.errno]
        else:
            cause = next((c for text, c in texts.items() if text in str(seen)), None)
        seen = seen.__cause__ or seen.__context__
    cause = cause or _folder_cause(folder)
    if cause is None:
        return None
    return error(f"cannot write in {folder}: {cause} (nothing incomplete was left under a final name)")


def _folder_cause(folder: str) -> str | None:
    """Why nothing can be written in ``folder`` as it is now (None: it seems writable)."""
    try:
        fs = os.statvfs(folder)
    except OSError:
        return None
    if fs.f_flag & os.ST_RDONLY:
        return WRITE_CAUSES[errno.EROFS]
    if fs.f_bavail * fs.f_frsize < NEARLY_FULL_BYTES:
        return WRITE_CAUSES[errno.ENOSPC]
    if not os.access(folder, os.W_OK | os.X_OK):
        return WRITE_CAUSES[errno.EACCES]
    return None


def _temp_beside(path: str) -> str:
    """A free name in ``path``'s folder for its temporary version, hidden and ending like ``path`` (a
    writer that picks the format by extension picks the same one)."""
    folder, name = os.path.split(os.path.abspath(path))
    stem, ext = os.path.splitext(name)
    return os.path.join(folder, f".{stem}{_TEMP_MARK}{os.urandom(4).hex()}{ext}")


def _remove_temp(temp: str) -> None:
    """Remove ``temp`` and what a writer made beside it under its name (SQLite's ``-journal``, ...)."""
    import shutil

    folder, name = os.path.split(temp)
    prefix = _temp_prefix(name)
    for entry in folder_names(folder):
        if entry.startswith(prefix):
            target = os.path.join(folder, entry)
            if os.path.isdir(target) and not os.path.islink(target):
                shutil.rmtree(target, ignore_errors=True)
            else:
                try:
                    os.remove(target)
                except OSError:
                    pass


def _temp_prefix(name: str) -> str:
    """``.rx-partial-1a2b3c4d`` of a temporary name: what the files a writer made beside it share."""
    return name[:name.index(_TEMP_MARK) + len(_TEMP_MARK) + 8]


def _put_all_in_place(temp: str, path: str) -> None:
    """Rename ``temp`` to ``path`` and the files a writer made beside it (a CSV's ``.prj``, a
    shapefile's ``.dbf``) to the same names beside ``path``; ``path`` itself last."""
    folder, name = os.path.split(temp)
    prefix, stem = _temp_prefix(name), os.path.splitext(os.path.basename(path))[0]
    for entry in folder_names(folder):
        if entry.startswith(prefix) and entry != name:
            _put_in_place(os.path.join(folder, entry), os.path.join(folder, stem + entry[len(prefix):]))
    _put_in_place(temp, path)


def _put_in_place(temp: str, path: str) -> None:
    """Rename ``temp`` to ``path``; a folder into a folder already there entry by entry (what else it
    holds stays)."""
    if os.path.isdir(temp) and os.path.isdir(path) and not os.path.islink(path):
        for name in os.listdir(temp):
            _put_in_place(os.path.join(temp, name), os.path.join(path, name))
        os.rmdir(temp)
    else:
        os.replace(temp, path)


class _Held(logging.Handler):
    """Holds what the libraries print during a write until its outcome is known: GDAL's log records
    (through rasterio's and pyogrio's loggers) and what C code writes on stderr (libtiff's
    ``_tiffWriteProc: No space left on device.``, into a memory file: the disk may be full)."""

    LOGGERS = ("rasterio", "pyogrio")

    def __init__(self):
        super().__init__()
        self.records: list[logging.LogRecord] = []
        self.fds: tuple[int, int] | None = None  # (memory file, stderr as it was)

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def __enter__(self) -> _Held:
        for name in self.LOGGERS:
            logging.getLogger(name).addHandler(self)
        if hasattr(os, "memfd_create"):
            sys.stderr.flush()
            self.fds = (os.memfd_create("vrsim-held-stderr"), os.dup(2))
            os.dup2(self.fds[0], 2)
        return self

    def done(self, shown: bool) -> None:
        """Stop holding; what was held goes on to stderr if ``shown`` (dropped: the one line says it)."""
        for name in self.LOGGERS:
            logging.getLogger(name).removeHandler(self)
        if self.fds is not None:
            sys.stderr.flush()
            held, stderr = self.fds
            os.dup2(stderr, 2)
            os.close(stderr)
            os.lseek(held, 0, os.SEEK_SET)
            while shown and (chunk := os.read(held, 1 << 16)):
                os.write(2, chunk)
            os.close(held)
        for record in self.records if shown else ():
            logging.getLogger(record.name).handle(record)


@contextmanager
def written(path: str, error=VrsimError):
    """Write ``path`` whole or not at all: yields a free temporary name in the same folder (hidden,
    ending like ``path``; the writer creates it, a file or a folder), renamed to ``path`` when the block
    ends without an exception (with the files the writer made beside it under the same stem, renamed
    to ``path``'s stem), removed otherwise.

    A failure for lack of space or permission becomes one line naming the folder and the cause
    (`write_failure`, raised as ``error``), and GDAL's own lines about it are dropped; other
    exceptions pass unchanged (the temporary is removed either way).
    """
    folder = os.path.dirname(os.path.abspath(path))
    temp = _temp_beside(path)
    held = _Held().__enter__()
    try:
        yield temp
        _put_all_in_place(temp, path)
        held.done(shown=True)
    except BaseException as exc:
        failure = write_failure(exc, folder, error) if isinstance(exc, Exception) else None
        held.done(shown=failure is None)
        _remove_temp(temp)
        if failure is not None:
            raise failure from None
        raise


@contextmanager
def staged(folder: str, last: tuple[str, ...] = (), error=VrsimError):
    """Write several files of ``folder`` as one: yields a temporary folder inside it (created, along
    with ``folder`` if missing) where the caller writes each file under its final name. When the block
    ends without an exception its entries are moved into ``folder`` (replacing same-named ones; the
    names in ``last`` last, in that order: a completion mark); otherwise nothing under a final name
    changes, the temporary folder is removed, and a ``folder`` this call created too.

    Errors, and GDAL's log lines, as `written`.
    """
    created = not os.path.isdir(folder)
    stage = _temp_beside(os.path.join(folder, "staged"))
    held = _Held().__enter__()
    try:
        try:
            os.makedirs(stage)
        except OSError as exc:
            raise write_failure(exc, os.path.abspath(folder), error) or error(
                f"{folder}: cannot create the folder ({exc.strerror})") from None
        yield stage
        entries = sorted(os.listdir(stage), key=lambda n: (n in last, last.index(n) if n in last else 0))
        for name in entries:
            _put_in_place(os.path.join(stage, name), os.path.join(folder, name))
        os.rmdir(stage)
        held.done(shown=True)
    except BaseException as exc:
        failure = write_failure(exc, os.path.abspath(folder), error) if isinstance(exc, Exception) else None
        held.done(shown=failure is None)
        _remove_temp(stage)
        if created:
            try:
                os.rmdir(folder)
            except OSError:
                pass
        if failure is not None:
            raise failure from None
        raise
