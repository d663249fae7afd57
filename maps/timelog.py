"""ISO 11783-10 TimeLogs: what a task controller logged during a task, read into columns and written.

A task (``TSK``) in TASKDATA.XML references its TimeLogs as ``<TLG A="TLG00001" C="1"/>`` (A: the
file name without extension; C: 1, a binary time log). Each is a pair of files beside TASKDATA.XML:

* ``TLG00001.XML``, the header: one ``<TIM A="" D="4">`` element holding an optional ``<PTN>`` and a
  list of ``<DLV A="ddi" B="" C="DET-n"/>`` (the data log values, by index in that list);
* ``TLG00001.BIN``, the records, little-endian, one after the other:

  =================  ======  ==================================================================
  time of day        uint32  ms since midnight (TIM A; always in the binary)
  date               uint16  days since 1980-01-01
  PTN A north        int32   latitude, 1e-7 degree
  PTN B east         int32   longitude, 1e-7 degree
  PTN C up           int32   altitude, mm
  PTN D status       uint8   0 no fix, 1 GNSS, 2 DGNSS, 3 precise GNSS, 4 RTK fixed, 5 RTK float,
                             6 dead reckoning, 7 manual, 8 simulated, 14 error, 15 not available
  PTN E PDOP         uint16  0.1
  PTN F HDOP         uint16  0.1
  PTN G satellites   uint8
  PTN H GPS time     uint32  ms since midnight (UTC)
  PTN I GPS date     uint16  days since 1980-01-01
  count              uint8   n, the values in this record
  n x (index, value) uint8,  index into the header's DLV list; the value in the DDI's unit
                     int32
  =================  ======  ==================================================================

A PTN attribute that is present and empty is in every record; one with a value holds that value for
every record (and is not in the binary); an absent one is not logged. A record carries only the DLVs
that the task controller logged at that moment (terminals log on change or on a timer), so most DDIs
have values in some records only. The layout was checked against the open-source isoxml-js and
isoxml-dotnet readers. A DLV's B attribute (a value) in a TimeLog header is not per-record data and
is not used.

The binary is parsed with numpy: one pass in Python finds where each record starts (each record's
length depends on its count byte), then every field of every record is gathered as arrays.
"""

from __future__ import annotations

import array
import io
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from vrsim.common import MapError, files
from vrsim.maps.ddi import ddi_list
from vrsim.maps.isoxml import TaskdataFolder, parse_xml, typed_attr

MAX_TLG_BYTES = 256 * 1024 * 1024  # default cap on one binary: ~3 M records of 20 values
# Memory the decoding takes (peak RSS measured, rounded up): per record, 5 bytes for each of
# the header's DLVs (values int32, logged bool) and its time, position and offset columns; per
# logged (index, value) pair, the index arrays that scatter it. 255 DLVs make a 7-byte record
# (time and count only) decode into 1.4 KB: a 64 MB binary into 13 GB.
DECODED_BYTES_PER_DLV = 5
DECODED_BYTES_PER_RECORD = 160
DECODED_BYTES_PER_PAIR = 120
EPOCH = np.datetime64("1980-01-01T00:00:00", "ms")
MS_PER_DAY = 86_400_000
NOT_AVAILABLE = 15  # PTN D: position status not available

# PTN attribute -> (column, binary dtype, scale from the binary to the column, scale from a header value)
PTN_FIELDS = {
    "A": ("lat_deg", "<i4", 1e-7, 1.0),
    "B": ("lon_deg", "<i4", 1e-7, 1.0),
    "C": ("up_m", "<i4", 1e-3, 1e-3),
    "D": ("status", "u1", 1.0, 1.0),
    "E": ("pdop", "<u2", 0.1, 1.0),
    "F": ("hdop", "<u2", 0.1, 1.0),
    "G": ("satellites", "u1", 1.0, 1.0),
    "H": ("gps_utc_time_ms", "<u4", 1.0, 1.0),
    "I": ("gps_utc_date_days", "<u2", 1.0, 1.0),
}


@dataclass(frozen=True, eq=False)
class TimeLog:
    """One TimeLog as columns: record i is row i of every array.

    Attributes
    ----------
    name : str
        ``"TLG00001"``.
    task : str
        The id (``TSK`` A) of the task that references it.
    source : str
        The TASKDATA it was read from.
    time : ndarray of datetime64[ms], shape (n,)
        When each record was logged, by the task controller's clock (ISO 11783 leaves the time zone
        to the terminal; usually local time).
    position : dict of str -> ndarray of float64, shape (n,)
        ``lat_deg``, ``lon_deg`` (WGS84), ``up_m``, ``status``, ``pdop``, ``hdop``, ``satellites``,
        ``gps_utc_time_ms``, ``gps_utc_date_days``: the PTN columns the header declares (in the
        binary or constant); NaN where the header does not log one.
    ddi : ndarray of int64, shape (k,)
        The DDI of each DLV in the header, in header order.
    element : tuple of str, length k
        The device element (``DET`` id) of each DLV.
    values : ndarray of int32, shape (n, k)
        The logged values in each DDI's unit; 0 where not logged.
    logged : ndarray of bool, shape (n, k)
        Whether record i carries a value for DLV j.
    """

    name: str
    task: str
    source: str
    time: np.ndarray
    position: dict
    ddi: np.ndarray
    element: tuple
    values: np.ndarray
    logged: np.ndarray

    @property
    def records(self) -> int:
        return int(self.time.size)

    @property
    def lat_deg(self) -> np.ndarray:
        return self.position["lat_deg"]

    @property
    def lon_deg(self) -> np.ndarray:
        return self.position["lon_deg"]

    @property
    def time_s(self) -> np.ndarray:
        """Seconds since the first record, float64."""
        if self.time.size == 0:
            return np.zeros(0)
        return (self.time - self.time[0]).astype(np.int64) / 1000.0

    def column(self, ddi: int, element: str | None = None) -> int:
        """Index of the DLV logging `ddi` (on `element` if given); MapError if none or several."""
        hits = [j for j, (d, e) in enumerate(zip(self.ddi, self.element, strict=True))
                if d == ddi and (element is None or e == element)]
        where = f"{self.source}: {self.name}"
        if not hits:
            on = f" on {element}" if element else ""
            raise MapError(f"{where} logs no DDI {ddi:04X}{on}; it logs DDI {ddi_list(np.unique(self.ddi))}")
        if len(hits) > 1:
            raise MapError(f"{where} logs DDI {ddi:04X} on several device elements "
                           f"{[self.element[j] for j in hits]}; name one")
        return hits[0]

    def value(self, ddi: int, element: str | None = None, hold: bool = False) -> np.ndarray:
        """The values of one DDI as float64, NaN in records that do not log it.

        With ``hold=True`` each record without a value takes the last logged one (task controllers
        log many values only on change); records before the first logged value stay NaN.
        """
        j = self.column(ddi, element)
        present = self.logged[:, j]
        out = np.where(present, self.values[:, j], np.nan)
        if hold and out.size:
            last = np.maximum.accumulate(np.where(present, np.arange(out.size), -1))
            out = np.where(last >= 0, out[np.maximum(last, 0)], np.nan)
        return out

    def count(self, ddi: int, element: str | None = None) -> int:
        """Number of records carrying a value of `ddi`."""
        return int(self.logged[:, self.column(ddi, element)].sum())


# ---------------------------------------------------------------------- reading
def read_timelogs(path, max_bytes: int = MAX_TLG_BYTES) -> list[TimeLog]:
    """Read every TimeLog that a TASKDATA's tasks reference, in document order, or one lone TimeLog.

    Parameters
    ----------
    path : str or os.PathLike
        The TASKDATA: a folder, its TASKDATA.XML, or a .zip holding one; or a lone TimeLog header
        ``TLGnnnnn.xml`` with its ``.bin`` beside it (positions and DDIs from its header; its task
        unknown, ``""``).
    max_bytes : int
        Refuse a TimeLog binary larger than this (default 256 MiB).

    Raises
    ------
    MapError
        If no task references a TimeLog, a file is missing, a header is malformed, or a binary is
        truncated or inconsistent with its header (naming the file and the record).
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MapError(f"{path}: no such file or folder")
    if is_lone_timelog(path):
        name = os.path.splitext(os.path.basename(path))[0]
        with TaskdataFolder(path) as folder:
            return [_read_one(folder, path, "", ET.Element("TLG", A=name, C="1"), max_bytes)]
    with TaskdataFolder(path) as folder:
        root = parse_xml(folder.read_xml(), path, "TASKDATA.XML", "ISO11783_TaskData")
        refs = [(task.get("A") or "", tlg) for task in root.iter("TSK") for tlg in task.findall("TLG")]
        if not refs:
            raise MapError(f"{path}: no task (TSK) references a TimeLog (TLG): nothing was logged")
        return [_read_one(folder, path, task, tlg, max_bytes) for task, tlg in refs]


def is_lone_timelog(path: str) -> bool:
    """True for a file named like a TimeLog header, ``TLGnnnnn.xml`` (any letter case)."""
    name = os.path.basename(path).upper()
    return not os.path.isdir(path) and re.fullmatch(r"TLG\d{5}\.XML", name) is not None


def _read_one(folder: TaskdataFolder, path: str, task: str, tlg, max_bytes: int) -> TimeLog:
    name = tlg.get("A")
    if not name:
        raise MapError(f"{path}: task {task}: TLG has no file name (attribute A)")
    kind = tlg.get("C", "1")
    if kind != "1":
        raise MapError(f"{path}: {name}: TLG C={kind!r}: only binary TimeLogs (C=1) are defined")
    for ext in (".XML", ".BIN"):
        if folder.size(name + ext) is None:
            beside = f"(task {task}) is missing beside TASKDATA.XML" if task else "is missing beside it"
            raise MapError(f"{path}: the TimeLog file {name}{ext} {beside}")
    where = f"{path}: {name}"
    header = parse_xml(folder.read(name + ".XML", files.cap_for("xml")), path, f"{name}.XML", "TIM")
    ptn, dlvs = _header(header, where)
    data = folder.read(name + ".BIN", max_bytes)
    time, columns, values, logged = _parse_records(data, ptn, len(dlvs), f"{where}.BIN")
    ddi = np.array([d for d, _ in dlvs], dtype=np.int64)
    return TimeLog(name=name, task=task, source=path, time=time, position=columns, ddi=ddi,
                   element=tuple(e for _, e in dlvs), values=values, logged=logged)


def _header(tim, where: str):
    """(PTN layout, DLV list) of a TimeLog header: layout {attribute: None (binary) or constant}."""
    ptns = tim.findall("PTN")
    if len(ptns) > 1:
        raise MapError(f"{where}.XML: {len(ptns)} PTN elements; a TimeLog header has at most one")
    layout = {}
    if ptns:
        for key in PTN_FIELDS:
            raw = ptns[0].get(key)
            if raw is None:
                continue
            layout[key] = None if raw == "" else typed_attr(ptns[0], key, float, f"{where}.XML")
    dlvs = []
    for i, dlv in enumerate(tim.findall("DLV")):
        ddi = typed_attr(dlv, "A", "hex", f"{where}.XML: DLV {i}")
        dlvs.append((ddi, dlv.get("C") or ""))
    if len(dlvs) > 255:
        raise MapError(f"{where}.XML: {len(dlvs)} DLVs; a record can index at most 255")
    return layout, dlvs


def _parse_records(data: bytes, layout: dict, k: int, where: str):
    """Time, PTN columns, values (n, k) and logged (n, k) of every record in a TimeLog binary."""
    binary = [key for key in PTN_FIELDS if key in layout and layout[key] is None]
    offsets, pos = {}, 6
    for key in binary:
        offsets[key] = pos
        pos += np.dtype(PTN_FIELDS[key][1]).itemsize
    fixed = pos  # bytes before the count byte
    starts = _record_starts(data, fixed, where)
    _check_decoded_size(starts.size, (len(data) - starts.size * (fixed + 1)) // 5, k, where)
    buf = np.frombuffer(data, dtype=np.uint8)
    ms = _gather(buf, starts, 0, "<u4").astype(np.int64)
    days = _gather(buf, starts, 4, "<u2").astype(np.int64)
    # No check that ms < 24 h: real terminals log midnight as 86,400,000 ms of the day before.
    time = EPOCH + (days * MS_PER_DAY + ms).astype("timedelta64[ms]")
    n = starts.size
    columns = {}
    for key, (column, dtype, scale, header_scale) in PTN_FIELDS.items():
        if key in offsets:
            columns[column] = _gather(buf, starts, offsets[key], dtype).astype(np.float64) * scale
        elif key in layout:
            columns[column] = np.full(n, layout[key] * header_scale)
        else:
            columns[column] = np.full(n, np.nan)
    values, logged = _values(buf, starts, fixed, k, where)
    return time, columns, values, logged


def _record_starts(data: bytes, fixed: int, where: str) -> np.ndarray:
    """Byte offset of each record (a record's length is fixed + 1 + 5 x its count byte), 8 bytes a
    record (a list of ints would take 36)."""
    starts = array.array("q")
    append = starts.append
    pos, end = 0, len(data)
    while pos < end:
        if pos + fixed >= end:
            raise MapError(f"{where}: record {len(starts)} (byte {pos}) is truncated: {end - pos} bytes "
                           f"left, its time and position need {fixed} and a count byte")
        append(pos)
        pos += fixed + 1 + 5 * data[pos + fixed]
    if pos > end:
        count = data[starts[-1] + fixed]
        raise MapError(f"{where}: record {len(starts) - 1} (byte {starts[-1]}) is truncated: it declares "
                       f"{count} values ({5 * count} bytes) but the file ends {pos - end} bytes short")
    return np.frombuffer(starts, dtype=np.int64) if starts else np.zeros(0, dtype=np.int64)


def _check_decoded_size(records: int, pairs: int, k: int, where: str) -> None:
    """Refuse a binary whose decoded arrays (`records` x `k` DLVs, `pairs` logged values) would not
    fit (`files.check_memory`), before they are allocated: a TimeLog's header may declare 255 DLVs
    for records of 7 bytes each."""
    need = records * (k * DECODED_BYTES_PER_DLV + DECODED_BYTES_PER_RECORD) + pairs * DECODED_BYTES_PER_PAIR
    files.check_memory(need, f"decoding {records:,} records of {k} DLVs", where, MapError)


def _gather(buf: np.ndarray, starts: np.ndarray, offset: int, dtype: str) -> np.ndarray:
    """One fixed-position field of every record (`offset` bytes into it), in its binary type."""
    size = np.dtype(dtype).itemsize
    return np.ascontiguousarray(buf[(starts + offset)[:, None] + np.arange(size)]).view(dtype).ravel()


def _values(buf, starts, fixed: int, k: int, where: str):
    """(values, logged), each (records, k): the (index, int32) pairs after each record's count byte."""
    n = starts.size
    counts = buf[starts + fixed].astype(np.int64)
    record = np.repeat(np.arange(n), counts)
    first = np.cumsum(counts) - counts
    slot = np.arange(record.size) - first[record]
    at = starts[record] + fixed + 1 + 5 * slot
    index = buf[at].astype(np.int64)
    bad = np.flatnonzero(index >= k)
    if bad.size:
        i = int(record[bad[0]])
        raise MapError(f"{where}: record {i} (byte {int(starts[i])}) has a value for DLV index "
                       f"{int(index[bad[0]])}, but the header declares {k} DLVs (0 to {k - 1})")
    flat = record * k + index
    if np.unique(flat).size != flat.size:
        order = np.sort(flat)
        i = int(order[np.flatnonzero(np.diff(order) == 0)[0]] // k)
        raise MapError(f"{where}: record {i} (byte {int(starts[i])}) logs one DLV twice")
    raw = np.ascontiguousarray(buf[(at + 1)[:, None] + np.arange(4)]).view("<i4").ravel()
    values = np.zeros(n * k, dtype=np.int32)
    logged = np.zeros(n * k, dtype=bool)
    values[flat] = raw
    logged[flat] = True
    return values.reshape(n, k), logged.reshape(n, k)


# ---------------------------------------------------------------------- writing
# The layout vrsim writes: time, PTN north, east and status in every record.
WRITE_RECORD = np.dtype([("ms", "<u4"), ("days", "<u2"), ("north", "<i4"), ("east", "<i4"),
                         ("status", "u1"), ("count", "u1")])
WRITE_VALUE = np.dtype([("index", "u1"), ("value", "<i4")])


def encode_records(time: np.ndarray, lat_deg, lon_deg, status, values: np.ndarray,
                   logged: np.ndarray) -> bytes:
    """The binary of a TimeLog whose header has ``<PTN A="" B="" D=""/>`` and k DLVs.

    Parameters
    ----------
    time : ndarray of datetime64, shape (n,)
        When each record was logged (from 1980-01-01 on).
    lat_deg, lon_deg : array_like, shape (n,)
        WGS84 position; NaN (no fix) is written as 0, 0.
    status : array_like of int, shape (n,) or scalar
        PTN D position status per record (0 to 15).
    values : ndarray of int, shape (n, k)
        Values in each DDI's unit.
    logged : ndarray of bool, shape (n, k)
        Which values each record carries (at most 255).
    """
    time = np.asarray(time).astype("datetime64[ms]")
    since = (time - EPOCH).astype(np.int64)
    if since.size and since.min() < 0:
        raise MapError(f"TimeLog: time {time[np.argmin(since)]} is before 1980-01-01, which the format "
                       "cannot hold")
    n = since.size
    logged = np.asarray(logged, dtype=bool).reshape(n, -1)
    head = np.zeros(n, dtype=WRITE_RECORD)
    head["days"], head["ms"] = np.divmod(since, MS_PER_DAY)
    lat, lon = (np.asarray(v, dtype=np.float64) for v in (lat_deg, lon_deg))
    fix = np.isfinite(lat) & np.isfinite(lon)
    head["north"] = np.where(fix, np.rint(np.where(fix, lat, 0.0) * 1e7), 0)
    head["east"] = np.where(fix, np.rint(np.where(fix, lon, 0.0) * 1e7), 0)
    head["status"] = np.broadcast_to(status, n)
    head["count"] = logged.sum(axis=1)
    # Every record with all k (index, value) pairs, then the pairs not logged left out (row by row).
    full = np.zeros(n, dtype=[("head", WRITE_RECORD), ("pairs", WRITE_VALUE, (logged.shape[1],))])
    full["head"] = head
    full["pairs"]["index"] = np.arange(logged.shape[1])
    full["pairs"]["value"] = values
    keep = np.concatenate([np.ones((n, WRITE_RECORD.itemsize), bool),
                           np.repeat(logged, WRITE_VALUE.itemsize, axis=1)], axis=1)
    return full.view(np.uint8).reshape(n, -1)[keep].tobytes()


def header_xml(ddis, elements) -> bytes:
    """The TimeLog header for `encode_records`: TIM, PTN north/east/status, one DLV per DDI."""
    tim = ET.Element("TIM", A="", D="4")
    ET.SubElement(tim, "PTN", A="", B="", D="")
    for ddi, element in zip(ddis, elements, strict=True):
        ET.SubElement(tim, "DLV", A=f"{int(ddi):04X}", B="", C=element)
    ET.indent(tim)
    out = io.BytesIO()
    ET.ElementTree(tim).write(out, encoding="utf-8", xml_declaration=True)
    return out.getvalue()
