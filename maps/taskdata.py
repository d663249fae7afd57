"""As-applied logs as ISO 11783-10 TASKDATA: a task with the implement's device description and a
TimeLog, written from a `PointLog` and read back into one.

What `write_taskdata` writes into its folder:

* ``TASKDATA.XML``: a task (``TSK``, status completed) with its time (``TIM``), the allocation of
  the device (``DAN``) and the reference to the TimeLog (``TLG``); the device (``DVC``) described as
  task controllers receive it from an implement: a device element for the device (type 1), one for
  the boom (type 2, function) carrying the logged process data (``DPD``), and one per section
  (type 4) with its lateral offset and width as properties (``DPT``, DDI 134, 135, 67); value
  presentations (``DVP``) say how to show rates in kg/ha (L/ha) and widths in m.
* ``TLG00001.xml`` / ``TLG00001.bin`` (see `maps.timelog`; lower-case extensions as task
  controllers write them and isoxml-js expects them): per record the time, PTN north/east
  (1e-7 degree) and position status, and on the boom: DDI 6 setpoint and DDI 7 actual mass per area
  application rate (mg/m^2; 1 kg/ha = 100 mg/m^2), or for a log of volume rates DDI 1 and 2
  (0.01 mm^3/m^2; 1 L/ha = 10,000), DDI 141 actual work state (1 on, 0 off), DDI 67
  actual working width (mm) and DDI 161 actual condensed work state 1-16 (two bits per section,
  section 1 the leftmost in the lowest bits: 01 on, 00 off, 11 not installed; DDI 162 ... for
  sections 17 and up).

Every record carries every value it has (a rate that is NaN is left out of that record): a log at
1 Hz, as terminals log, stays small and a reader needs no hold-last-value logic.
"""

from __future__ import annotations

import io
import itertools
import os
import xml.etree.ElementTree as ET

import numpy as np

from vrsim.common import MapError, __version__, files
from vrsim.maps import ddi as DDI
from vrsim.maps.crs import WGS84
from vrsim.maps.pointlog import NOT_AVAILABLE, PointLog
from vrsim.maps.timelog import encode_records, header_xml, read_timelogs
from vrsim.maps.units import is_rate_unit, rate_kind

TLG_NAME = "TLG00001"
BOOM = "DET-2"
MAX_SECTIONS = DDI.SECTIONS_PER_CONDENSED * DDI.MAX_CONDENSED_DDIS


def is_taskdata(path: str) -> bool:
    """True for a folder (unless it holds shapefiles and no TASKDATA.XML), a ``.xml`` file, or a zip
    archive holding a TASKDATA.XML."""
    if os.path.isdir(path):
        names = [n.lower() for n in os.listdir(path)]
        return "taskdata.xml" in names or "taskdata" in names or not any(n.endswith(".shp") for n in names)
    if path.lower().endswith(".xml"):
        return True
    if path.lower().endswith(".zip"):
        with files.open_zip(path, MapError) as z:  # a regular file, members counted and sized first
            return any(os.path.basename(n).lower() == "taskdata.xml" for n in z.namelist())
    return False


# ---------------------------------------------------------------------- writing
def write_taskdata(log: PointLog, folder, section_widths_m, task: str = "vrsim run",
                   device: str = "vrsim implement") -> str:
    """Write `log` as a TASKDATA folder with one task, the implement and one TimeLog.

    Parameters
    ----------
    log : PointLog
        The records (any CRS: positions are written in WGS84); rates in a mass-per-area unit
        (converted to mg/m^2, DDI 6 and 7) or a volume-per-area unit (DDI 1 and 2); `log.start` is
        required (TimeLog times are absolute).
    folder : str or os.PathLike
        Created if missing (its parent must exist); refused if it already holds a TASKDATA.XML.
    section_widths_m : sequence of float
        The implement's sections, left to right, m; their sum is the full working width.
        `log.sections_on` must have one column per section, or none (all sections follow
        `log.work_on`).
    task, device : str
        Designators of the task and of the device.

    Returns
    -------
    str
        The path of TASKDATA.XML.
    """
    folder = os.fspath(folder)
    widths = _section_widths(section_widths_m, log)
    if log.start is None:
        raise MapError("write_taskdata: the log has no start time (PointLog.start); a TimeLog needs "
                       "absolute times")
    unit = _rate_ddis(log)[3]
    rates = log.in_unit(unit)
    lon, lat = rates.lonlat()
    sections = rates.sections_on if rates.sections_on.shape[1] else np.repeat(
        rates.work_on[:, None], widths.size, axis=1)
    ddis, values, logged = _records(rates, sections)
    prepare_folder(folder)
    time_s = np.where(np.isfinite(log.time_s), log.time_s, 0.0)
    time = log.start + np.rint(time_s * 1000).astype("timedelta64[ms]")
    binary = encode_records(time, lat, lon, rates.gnss_status, values, logged)
    files = {
        f"{TLG_NAME}.xml": header_xml(ddis, [BOOM] * len(ddis)),
        f"{TLG_NAME}.bin": binary,
        "TASKDATA.XML": _taskdata_xml(widths, ddis, time, task, device),
    }
    for name, data in files.items():
        try:
            with open(os.path.join(folder, name), "wb") as f:
                f.write(data)
        except OSError as exc:
            raise MapError(f"{folder}: cannot write {name}: {exc.strerror}") from None
    return os.path.join(folder, "TASKDATA.XML")


def _section_widths(section_widths_m, log: PointLog) -> np.ndarray:
    widths = np.asarray(section_widths_m, dtype=np.float64).ravel()
    if not (1 <= widths.size <= MAX_SECTIONS) or not np.all(np.isfinite(widths) & (widths > 0)):
        raise MapError(f"write_taskdata: section_widths_m={list(widths)} must be 1 to {MAX_SECTIONS} "
                       "positive widths")
    if log.sections_on.shape[1] not in (0, widths.size):
        raise MapError(f"write_taskdata: the log has {log.sections_on.shape[1]} section columns but the "
                       f"implement {widths.size} sections")
    return widths


def prepare_folder(folder: str) -> None:
    """Create a TASKDATA folder (its parent must exist), refusing one that holds a TASKDATA.XML
    (`MapError`): what `write_taskdata` does first, for a caller that must know before it writes
    anything else."""
    parent = os.path.dirname(os.path.abspath(folder))
    if not os.path.isdir(parent):
        raise MapError(f"{folder}: folder {parent} does not exist")
    if os.path.isdir(folder) and any(n.upper() == "TASKDATA.XML" for n in os.listdir(folder)):
        raise MapError(f"{folder}: already holds a TASKDATA.XML; vrsim does not overwrite a TASKDATA "
                       "(its files belong together): choose a new folder")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise MapError(f"{folder}: cannot create the folder: {exc.strerror}") from None


# The TimeLog's rate DDIs by the kind of the log's unit: (setpoint, actual, its unit per count, in).
_RATE_DDIS = {"mass": (DDI.SETPOINT_MASS_PER_AREA, DDI.ACTUAL_MASS_PER_AREA, DDI.KG_HA_PER_MG_M2, "kg/ha"),
              "volume": (DDI.SETPOINT_VOLUME_PER_AREA, DDI.ACTUAL_VOLUME_PER_AREA, DDI.L_HA_PER_VOLUME_COUNT,
                         "L/ha"),
              "count": (DDI.SETPOINT_COUNT_PER_AREA, DDI.ACTUAL_COUNT_PER_AREA, DDI.SEEDS_HA_PER_COUNT,
                        "seeds/ha")}


def _rate_ddis(log: PointLog) -> tuple[int, int, float, str]:
    """The rate DDIs of a log in `log.unit` (`_RATE_DDIS`)."""
    kind = rate_kind(log.unit) if is_rate_unit(log.unit) else None
    if kind not in _RATE_DDIS:
        raise MapError(f"write_taskdata: a TimeLog holds mass, volume or count rates, not "
                       f"{log.unit or 'no unit'!r}")
    return _RATE_DDIS[kind]


def _records(log: PointLog, sections: np.ndarray):
    """(DDIs, values (n, k), logged (n, k)) of the boom's DLVs, in the TimeLog's units."""
    n = log.points
    setpoint, actual, per_count, _ = _rate_ddis(log)
    columns = [
        (setpoint, _int_or_missing(log.target / per_count, "target rate")),
        (actual, _int_or_missing(log.applied / per_count, "applied rate")),
        (DDI.ACTUAL_WORK_STATE, (log.work_on.astype(np.int64), np.ones(n, dtype=bool))),
        (DDI.ACTUAL_WORKING_WIDTH, _int_or_missing(log.width_m * 1000.0, "working width")),
    ]
    for g, state in enumerate(_condensed_work_states(sections)):
        columns.append((DDI.ACTUAL_CONDENSED_WORK_STATE_1_16 + g, (state, np.ones(n, dtype=bool))))
    ddis = [d for d, _ in columns]
    values = np.column_stack([v for _, (v, _) in columns]).astype(np.int32)
    logged = np.column_stack([m for _, (_, m) in columns])
    return ddis, values, logged


def _int_or_missing(values: np.ndarray, what: str):
    """Rounded int32 values and where they exist (NaN: not logged in that record)."""
    ok = np.isfinite(values)
    if (np.abs(values[ok]) > np.iinfo(np.int32).max).any():
        raise MapError(f"write_taskdata: a {what} of {np.nanmax(np.abs(values)):.0f} (TimeLog units) does "
                       "not fit an int32")
    return np.where(ok, np.rint(np.where(ok, values, 0.0)), 0).astype(np.int64), ok


def _condensed_work_states(sections: np.ndarray) -> list[np.ndarray]:
    """DDI 161, 162, ... values (int32 bit patterns) of per-section states (n, s), s <= 256.

    Two bits per section, section 1 (the leftmost) in the lowest two bits of DDI 161: 01 on, 00 off;
    the unused slots of the last group are 11 (not installed).
    """
    sections = np.asarray(sections, dtype=bool)
    n, s = sections.shape
    groups = -(-s // DDI.SECTIONS_PER_CONDENSED)
    padded = np.full((n, groups * DDI.SECTIONS_PER_CONDENSED), 3, dtype=np.uint64)
    padded[:, :s] = sections
    shifts = 2 * np.arange(DDI.SECTIONS_PER_CONDENSED, dtype=np.uint64)
    words = (padded.reshape(n, groups, -1) << shifts).sum(axis=2).astype(np.uint32)
    return [words[:, g].view(np.int32) for g in range(groups)]


def _sections_from_condensed(words: list[np.ndarray]) -> np.ndarray:
    """Per-section on/off (n, s) from condensed work states; trailing never-installed sections dropped."""
    if not words:
        return np.zeros((0, 0), dtype=bool)
    raw = np.column_stack([np.asarray(w).astype(np.int64) & 0xFFFFFFFF for w in words]).astype(np.uint64)
    shifts = 2 * np.arange(DDI.SECTIONS_PER_CONDENSED, dtype=np.uint64)
    states = ((raw[:, :, None] >> shifts) & np.uint64(3)).reshape(raw.shape[0], -1)
    installed = np.flatnonzero((states != 3).any(axis=0))
    s = int(installed[-1]) + 1 if installed.size else 0
    return states[:, :s] == 1


def _taskdata_xml(widths: np.ndarray, ddis, time: np.ndarray, task: str, device: str) -> bytes:
    root = ET.Element("ISO11783_TaskData", VersionMajor="4", VersionMinor="3",
                      ManagementSoftwareManufacturer="vrsim", ManagementSoftwareVersion=__version__,
                      TaskControllerManufacturer="vrsim", TaskControllerVersion=__version__,
                      DataTransferOrigin="2")
    tsk = ET.SubElement(root, "TSK", A="TSK1", B=task, G="4")
    if time.size:
        ET.SubElement(tsk, "TIM", A=_iso(time.min()), B=_iso(time.max()), D="4")
    ET.SubElement(tsk, "DAN", A=CLIENT_NAME, C="DVC-1")
    ET.SubElement(tsk, "TLG", A=TLG_NAME, C="1")
    _device(root, widths, ddis, device)
    ET.indent(root)
    out = io.BytesIO()
    ET.ElementTree(root).write(out, encoding="utf-8", xml_declaration=True)
    return out.getvalue()


# An ISO NAME (8 bytes) and labels (7 bytes) for a device that exists only in the simulation: the
# localization label says English, metric units (bytes in reverse order, as task controllers write it).
CLIENT_NAME = "A000860000000000"
STRUCTURE_LABEL = "7672696D303031"  # "vrim001"
LOCALIZATION_LABEL = "FF000000006E65"
TIME_INTERVAL, ON_CHANGE = 1, 8  # DPD trigger methods
DEFAULT_SET, SETTABLE = 1, 2  # DPD properties


def _device(root, widths: np.ndarray, ddis, name: str) -> None:
    """The DVC: device, boom (the logged DPDs) and sections (offset and width DPTs), as a TC gets it."""
    dvc = ET.SubElement(root, "DVC", A="DVC-1", B=name, C=__version__, D=CLIENT_NAME, F=STRUCTURE_LABEL,
                        G=LOCALIZATION_LABEL)
    ids = itertools.count(1)
    rate_dvp, width_dvp, device_id, boom_id = (str(next(ids)) for _ in range(4))
    ET.SubElement(dvc, "DET", A="DET-1", B=device_id, C="1", D=name, E="0", F="0")
    boom = ET.SubElement(dvc, "DET", A=BOOM, B=boom_id, C="2", D="boom", E="1", F=device_id)
    data, props = [], []
    for ddi in ddis:
        data.append(_dpd(next(ids), ddi, rate_dvp, width_dvp))
        ET.SubElement(boom, "DOR", A=data[-1]["A"])
    # ISO 11783 offsets: Y positive to the right, from the boom's centre; section 1 is the leftmost.
    right_mm = np.rint((np.cumsum(widths) - widths / 2 - widths.sum() / 2) * 1000).astype(np.int64)
    for i, width in enumerate(widths):
        det = ET.SubElement(dvc, "DET", A=f"DET-{3 + i}", B=str(next(ids)), C="4", D=f"section {i + 1}",
                            E=str(2 + i), F=boom_id)
        for ddi, value, label in ((DDI.DEVICE_ELEMENT_OFFSET_X, 0, "offset x"),
                                  (DDI.DEVICE_ELEMENT_OFFSET_Y, right_mm[i], "offset y"),
                                  (DDI.ACTUAL_WORKING_WIDTH, round(width * 1000), "width")):
            props.append({"A": str(next(ids)), "B": f"{ddi:04X}", "C": str(int(value)), "D": label,
                          "E": width_dvp})
            ET.SubElement(det, "DOR", A=props[-1]["A"])
    for tag, items in (("DPD", data), ("DPT", props)):  # the schema orders DET, DPD, DPT, DVP
        for attrs in items:
            ET.SubElement(dvc, tag, attrs)
    _, _, per_count, unit = next(v for v in _RATE_DDIS.values() if v[0] in ddis)
    ET.SubElement(dvc, "DVP", A=rate_dvp, B="0", C=f"{per_count:g}", D="2", E=unit)
    ET.SubElement(dvc, "DVP", A=width_dvp, B="0", C="0.001", D="3", E="m")


def _dpd(object_id: int, ddi: int, rate_dvp: str, width_dvp: str) -> dict:
    first = DDI.ACTUAL_CONDENSED_WORK_STATE_1_16
    if ddi >= first:
        group = ddi - first
        label, trigger = f"actual condensed work state {16 * group + 1}-{16 * group + 16}", ON_CHANGE
    else:
        label, trigger = DDI.NAMES[ddi], TIME_INTERVAL
    attrs = {"A": str(object_id), "B": f"{ddi:04X}",
             "C": str(DEFAULT_SET | (SETTABLE if ddi in (DDI.SETPOINT_MASS_PER_AREA,
                                                         DDI.SETPOINT_VOLUME_PER_AREA) else 0)),
             "D": str(trigger), "E": label}
    if ddi in {d for ddis in _RATE_DDIS.values() for d in ddis[:2]}:
        attrs["F"] = rate_dvp
    elif ddi == DDI.ACTUAL_WORKING_WIDTH:
        attrs["F"] = width_dvp
    return attrs


def _iso(t: np.datetime64) -> str:
    return str(np.datetime64(t, "s"))


# ---------------------------------------------------------------------- reading
def _parse_ddi(text) -> int:
    """A DDI as a user names it: decimal (``"7"``) or hexadecimal with ``0x`` (``"0x0007"``)."""
    try:
        value = int(str(text), 16) if str(text).lower().startswith("0x") else int(str(text))
    except ValueError:
        raise MapError(f"DDI {text!r} is not a number (decimal, or hexadecimal with 0x)") from None
    if not 0 <= value <= 0xFFFF:
        raise MapError(f"DDI {text!r} is outside 0 to 65535")
    return value


def read_taskdata_log(path, rate_ddi=None, target_ddi=None, product: str | None = None) -> PointLog:
    """The as-applied log in a TASKDATA's TimeLogs, as one `PointLog` in WGS84.

    Parameters
    ----------
    path : str or os.PathLike
        The TASKDATA (folder, TASKDATA.XML or .zip).
    rate_ddi, target_ddi : int or str, optional
        DDI of the applied and of the target rate (see `_parse_ddi`). Default: DDI 7 (actual mass per
        area, in kg/ha) if a TimeLog logs it, else DDI 2 (actual volume per area, in L/ha); the target
        is then the matching setpoint (6 or 1). Other DDIs are read in their own units (unit "").
    product : str, optional
        Where the rate is logged on several device elements (one per product, e.g. per bin): the
        product (``PDTn`` or its name, allocated to its element by the task's ``PAN``) or the element
        (``DET-n``) to read; such a log is refused without it, listing them.

    Notes
    -----
    Every TimeLog that logs the rate DDI contributes its records, in time order. Values logged only
    on change are held until the next one; records before a DDI's first value have NaN. Positions
    (0, 0), which terminals write without a fix, are NaN. Working width is DDI 67 (mm -> m), the
    work state DDI 141 (on when 1; on everywhere if not logged), the sections DDI 161 and up.
    """
    path = os.fspath(path)
    logs = read_timelogs(path)
    rate = _parse_ddi(rate_ddi) if rate_ddi is not None else _default_rate(path, logs)
    setpoint, unit, factor = DDI.RATES.get(rate, (None, "", 1.0))
    target = _parse_ddi(target_ddi) if target_ddi is not None else setpoint
    used = [t for t in logs if rate in t.ddi]
    if not used:
        found = sorted({int(d) for t in logs for d in t.ddi})
        raise MapError(f"{path}: no TimeLog logs DDI {rate:04X}; they log DDI {DDI.ddi_list(found)}")
    element = _rate_element(path, used, rate, product)
    parts = [_timelog_columns(t, rate, target, factor, element) for t in used]
    cols = {key: np.concatenate([p[key] for p in parts]) for key in parts[0] if key != "sections"}
    order = np.argsort(cols["time"], kind="stable")
    start = cols["time"][order[0]]
    return PointLog(cols["lon"][order], cols["lat"][order], WGS84, applied=cols["applied"][order],
                    target=cols["target"][order], unit=unit, start=start,
                    time_s=(cols["time"][order] - start).astype(np.int64) / 1000.0,
                    width_m=cols["width"][order], work_on=cols["work"][order],
                    sections_on=_stack_sections([p["sections"] for p in parts])[order],
                    gnss_status=cols["status"][order], source=path, format="taskdata")


def _default_rate(path: str, logs) -> int:
    for rate in DDI.RATES:
        if any(rate in t.ddi for t in logs):
            return rate
    found = sorted({int(d) for t in logs for d in t.ddi})
    raise MapError(f"{path}: no TimeLog logs an applied rate (DDI 0007 or 0002); they log DDI "
                   f"{DDI.ddi_list(found)}; name the rate's DDI (rate_field= / --rate-field)")


def _rate_element(path: str, logs, rate: int, product: str | None) -> str | None:
    """The device element whose rate is read: None where the rate is logged on one only (and no
    product named); else the element of `product` (MapError listing the elements and their products)."""
    elements = sorted({e for t in logs for d, e in zip(t.ddi, t.element, strict=True) if d == rate})
    if product is None and len(elements) <= 1:
        return None
    products = _products_by_element(path)
    listed = ", ".join(f"{e} ({products[e][0]} {products[e][1]!r})" if e in products else e for e in elements)
    if product is None:
        raise MapError(f"{path}: DDI {rate:04X} is logged on {len(elements)} device elements, one per "
                       f"product: {listed}; choose one with --product NAME|PDTn")
    wanted = product.strip().lower()
    for element in elements:
        pdt, name = products.get(element, ("", ""))
        if wanted in (element.lower(), pdt.lower(), name.lower()):
            return element
    raise MapError(f"{path}: no product {product!r} logs DDI {rate:04X}; logged on: {listed}")


def _products_by_element(path: str) -> dict[str, tuple[str, str]]:
    """{device element: (PDT id, product name)} from the tasks' product allocations (PAN A, E)."""
    from vrsim.maps.isoxml import TaskdataFolder, parse_xml
    from vrsim.maps.timelog import is_lone_timelog

    if is_lone_timelog(path):
        return {}
    with TaskdataFolder(path) as folder:
        root = parse_xml(folder.read_xml(), path, "TASKDATA.XML", "ISO11783_TaskData")
    names = {pdt.get("A"): pdt.get("B") or "" for pdt in root.iter("PDT")}
    return {pan.get("E"): (pan.get("A"), names.get(pan.get("A"), "")) for pan in root.iter("PAN")
            if pan.get("E") and pan.get("A")}


def _timelog_columns(t, rate: int, target: int | None, factor: float, element: str | None = None) -> dict:
    lat, lon = t.lat_deg.copy(), t.lon_deg.copy()
    no_fix = (lat == 0) & (lon == 0)
    lat[no_fix] = lon[no_fix] = np.nan
    has = set(int(d) for d in t.ddi)
    n = t.records
    condensed = [t.value(d, hold=True) for d in range(DDI.ACTUAL_CONDENSED_WORK_STATE_1_16,
                 DDI.ACTUAL_CONDENSED_WORK_STATE_1_16 + DDI.MAX_CONDENSED_DDIS) if d in has]
    words = [np.where(np.isnan(w), 0xFFFFFFFF, w).astype(np.int64) for w in condensed]
    status = t.position["status"]
    return {
        "time": t.time, "lat": lat, "lon": lon,
        "applied": t.value(rate, element, hold=True) * factor,
        "target": t.value(target, element, hold=True) * factor if target in has else np.full(n, np.nan),
        "width": t.value(DDI.ACTUAL_WORKING_WIDTH, hold=True) / 1000.0 if DDI.ACTUAL_WORKING_WIDTH in has
        else np.full(n, np.nan),
        "work": t.value(DDI.ACTUAL_WORK_STATE, hold=True) == 1 if DDI.ACTUAL_WORK_STATE in has
        else np.ones(n, dtype=bool),
        "status": np.where(np.isnan(status), NOT_AVAILABLE, status).astype(np.uint8),
        "sections": _sections_from_condensed(words) if words else np.zeros((n, 0), dtype=bool),
    }


def _stack_sections(parts: list[np.ndarray]) -> np.ndarray:
    """Per-section states of several TimeLogs, padded to the widest (sections not logged: off)."""
    s = max(p.shape[1] for p in parts)
    return np.concatenate([np.pad(p, ((0, 0), (0, s - p.shape[1]))) for p in parts])
