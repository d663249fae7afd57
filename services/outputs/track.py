"""The per-tick track: track.parquet (columnar, the default) and track.csv, one row per tick (time,
position, speed, shaft, current, rates, sections), the same columns and units in both.

Written part by part as a run accounts its ticks (`services.sim.bounded`: `TrackFiles` is its track
sink), or whole from an in-process run's arrays; each file whole or not at all (`common.written`: a
temporary name beside it, renamed when the run's outputs are done). A thread makes each part's table
and writes it (pyproj, numpy and Arrow work without the GIL: the run goes on meanwhile, on the other
core), at most `BACKLOG_PARTS` parts behind. Through pyarrow (177,000 rows in a
fraction of a second, where a row-by-row writer takes most of a second). In track.csv a value that does
not exist (a rate outside the map, the applied rate at a standstill) is an empty field, so GIS tools and
spreadsheets type the column as a number; in track.parquet it is null. Each column is rounded to its
resolution first, so the shortest text that reads back the same number is short.
"""

from __future__ import annotations

import contextlib
import os

import numpy as np

from vrsim.common import MapError
from vrsim.common.arrow import arrow_array
from vrsim.common.section_masks import section_mask_codes
from vrsim.common.written import write_failure, written

# (column, decimals): 0.001 s, 1e-8 degree (~1 mm), 1 mm/s, 0.001 rpm, 0.01 mA, 0.01 kg/ha; None: as is
TRACK_COLUMNS = (("time_s", 3), ("lat", 8), ("lon", 8), ("speed_m_s", 3), ("target_shaft_rpm", 3),
                 ("shaft_rpm", 3), ("current_a", 5), ("prescribed_kg_ha", 2), ("applied_kg_ha", 2),
                 ("implement_on", None), ("sections_on", None), ("section_mask", None))
PARTIAL_PREFIX = ".track-partial-"  # then the writing process's id: a killed run's is removed later


TRACK_FILES = {"parquet": "track.parquet", "csv": "track.csv"}   # ``[output] track``'s formats
# Parts handed to the writing thread and not yet written, at most: the track's memory stays a few
# parts' whatever the disk's speed.
BACKLOG_PARTS = 2


def _track_table(field, rows: dict):
    """The track's columns (`TRACK_COLUMNS`) of per-tick `rows` (`services.sim.bounded.BoundedAccount`'s
    track rows), as a pyarrow table. ``sections_on`` counts the sections whose gates are open in the
    tick, ``section_mask`` says which (hexadecimal bitmask, bit k the k-th section from the left:
    `common.section_masks.section_masks`)."""
    import pyarrow as pa

    lon, lat = field.to_wgs84(rows["x_m"], rows["y_m"])
    gates = np.asarray(rows["sections_on"], bool)
    codes, masks = section_mask_codes(gates)
    values = (rows["time_s"], lat, lon, rows["speed_m_s"], rows["target_shaft_rpm"], rows["shaft_rpm"],
              rows["current_a"], rows["prescribed_kg_ha"], rows["applied_kg_ha"],
              np.asarray(rows["implement_on"], np.int8), gates.sum(axis=1, dtype=np.int16))
    # NaN as null, written as "" (`arrow_array`: pa.array would load pandas into the run's process)
    columns = {name: arrow_array(v if decimals is None else np.round(np.asarray(v, float), decimals), True)
               for (name, decimals), v in zip(TRACK_COLUMNS[:-1], values, strict=True)}  # the masks next
    # Each distinct mask's text once, then taken per tick: a plain text column (parts of a run have
    # masks of their own).
    columns["section_mask"] = arrow_array(masks).take(arrow_array(codes.astype(np.int32)))
    return pa.table(columns)



class TrackFiles:
    """The track's files in `folder` (`TRACK_FILES` of `formats`), written part by part (call it with
    each part's rows) into a hidden folder of their own beside them, put in place by `finish`
    (`common.written`); `abort` removes them.

    Parameters
    ----------
    field : vehicle.Field
        The run's field (positions to WGS 84).
    folder : str
        Where the files go (created if missing; `abort` removes it again if it created it and it is
        empty).
    formats : sequence of str
        Keys of `TRACK_FILES`.
    """

    def __init__(self, field, folder: str, formats):
        import tempfile

        self.field, self.folder = field, folder
        self.created = not os.path.isdir(folder)
        self.partial = None
        self.paths = {f: os.path.join(folder, TRACK_FILES[f]) for f in formats}
        self._writers: dict = {}
        self._thread = None   # the writing thread (a one-thread pool), from the first part on
        self._pending: list = []   # the parts handed to it (futures), oldest first
        try:
            os.makedirs(folder, exist_ok=True)
            _remove_stale_partials(folder)
            self.partial = tempfile.mkdtemp(prefix=f"{PARTIAL_PREFIX}{os.getpid()}-", dir=folder)
        except OSError as exc:
            self._failed(exc)

    def __call__(self, rows: dict) -> None:
        """Write the next ticks' rows (in the writing thread; what went wrong there is raised by a later
        call or `finish`)."""
        if not self.paths:
            return
        rows = {k: np.array(rows[k]) for k in _ROW_KEYS}   # the thread's own: the run's may change
        self._settle(BACKLOG_PARTS - 1)
        if self._thread is None:
            from concurrent.futures import ThreadPoolExecutor

            self._thread = ThreadPoolExecutor(1, thread_name_prefix="track-files")
        self._pending.append(self._thread.submit(self._write, rows))

    def _write(self, rows: dict) -> None:
        table = _track_table(self.field, rows)
        if not self._writers:
            self._writers = {f: _writer(f, os.path.join(self.partial, TRACK_FILES[f]), table.schema)
                             for f in self.paths}
        for writer in self._writers.values():
            writer.write_table(table)

    def _settle(self, parts: int) -> None:
        """Wait until at most `parts` parts are still to be written; a failed write is raised here."""
        while len(self._pending) > parts:
            try:
                self._pending.pop(0).result()
            except OSError as exc:   # pyarrow's, a full disk say
                self._failed(exc)

    def _stop(self) -> None:
        """End the writing thread: the parts it has not begun are dropped, the one it writes finished."""
        if self._thread is not None:
            self._thread.shutdown(wait=True, cancel_futures=True)
            self._thread, self._pending = None, []

    def _failed(self, exc: OSError):
        """Remove what was written and raise the one line of a folder that takes no more
        (`common.written.write_failure`), else `exc`."""
        failure = write_failure(exc, os.path.abspath(self.folder), MapError)
        self.abort()
        if failure is not None:
            raise failure from None
        raise exc

    def finish(self) -> dict[str, str]:
        """Close the files and put them in place; {file name: path}."""
        try:
            self._settle(0)
            self._stop()
            if self.paths and not self._writers:   # no tick: the columns alone
                self._write({k: np.zeros((0, 0) if k == "sections_on" else 0) for k in _ROW_KEYS})
            for writer in self._writers.values():
                writer.close()
            self._writers = {}
            for fmt, path in self.paths.items():
                with written(path, error=MapError) as temp:
                    os.replace(os.path.join(self.partial, TRACK_FILES[fmt]), temp)
        except OSError as exc:   # closing a file on a full disk
            self._failed(exc)
        except BaseException:
            self.abort()
            raise
        os.rmdir(self.partial)
        return {TRACK_FILES[f]: p for f, p in self.paths.items()}

    def abort(self) -> None:
        """Remove what was written (nothing under a final name changes)."""
        import shutil

        self._stop()
        for writer in self._writers.values():
            with contextlib.suppress(Exception):
                writer.close()
        self._writers = {}
        if self.partial is not None:
            shutil.rmtree(self.partial, ignore_errors=True)
        if self.created:
            with contextlib.suppress(OSError):
                os.rmdir(self.folder)


def _writer(fmt: str, path: str, schema):
    """A pyarrow writer of `fmt` ("parquet" or "csv") into `path`."""
    if fmt == "parquet":
        import pyarrow.parquet as pq

        # A dictionary only for the columns of few values: tried on the measured ones, it is given up
        # after a page of distinct values, and the try took half of the writing's time.
        return pq.ParquetWriter(path, schema, compression="zstd",
                                use_dictionary=[name for name, decimals in TRACK_COLUMNS if decimals is None])
    import pyarrow.csv as pa_csv

    # Nothing here holds a comma or a quote: no quotes (the masks would get them by default).
    return pa_csv.CSVWriter(path, schema, write_options=pa_csv.WriteOptions(quoting_header="none",
                                                                             quoting_style="none"))


_ROW_KEYS = ("time_s", "x_m", "y_m", "speed_m_s", "implement_on", "target_shaft_rpm", "shaft_rpm",
             "current_a", "sections_on", "prescribed_kg_ha", "applied_kg_ha")


def track_rows(result) -> dict:
    """The per-tick rows of an in-process run's arrays (`services.sim.run.RunResult`), as a run
    accounted part by part hands them to its track files."""
    track, control, landing = result.track, result.control, result.landing
    rows = {k: v[k] for v, keys in ((track, _ROW_KEYS[:5]), (control, _ROW_KEYS[5:9])) for k in keys}
    return dict(rows, prescribed_kg_ha=landing.prescribed_kg_ha, applied_kg_ha=landing.applied_kg_ha)


def _remove_stale_partials(folder: str) -> list[str]:
    """Remove the ``.track-partial-<pid>-*`` folders in `folder` that a run killed before it could
    clean up left (their process is gone; one of an older vrsim, without a pid, too), saying so in one
    warning; the names removed."""
    import shutil
    import warnings

    removed = []
    for name in sorted(os.listdir(folder)):
        if not name.startswith(PARTIAL_PREFIX) or not os.path.isdir(os.path.join(folder, name)):
            continue
        pid = name[len(PARTIAL_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and _alive(int(pid)):
            continue
        shutil.rmtree(os.path.join(folder, name), ignore_errors=True)
        removed.append(name)
    if removed:
        warnings.warn(f"{folder}: removed {', '.join(removed)}: the unfinished track of a run that was "
                      "killed", UserWarning, stacklevel=3)
    return removed


def _alive(pid: int) -> bool:
    """Whether process `pid` runs (or runs under another user)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return pid != 0
