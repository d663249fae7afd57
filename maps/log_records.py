"""An as-applied log as the machine's records over time: one row per timestamp, each section's state.

A machine logs in one of two shapes, and `machine_records` turns either into the same rows:

* **one record per section per timestamp** (John Deere's per-section export, ``SECTIONID`` and
  ``SWATHWIDTH`` per record): the sections open at a timestamp are the ones with a record there; each
  section's width is its records' median ``SWATHWIDTH``; the sections are ordered left to right by
  their points' median offset across the heading from the timestamp's centre;
* **one record per timestamp** (a 1 Hz export, a TimeLog, vrsim's own logs): the machine's width in
  use per record (``SWATHWIDTH``, ``width_m``) is all that is known of its sections. The sections are
  the steps between the distinct widths logged (the narrowest width, then each next width's extra),
  so that the open sections' widths add up to each record's width; with per-section states logged
  (a TimeLog's condensed work states) those are used.

Ground speed comes from the log's speed, else its ``DISTANCE`` over the time since the previous
record, else the positions; both are smoothed over `SPEED_SMOOTH_S` (the timestamps of a 5 Hz
export jitter by 10 ms, which makes a raw distance over time jump by 5 %). Records more than
`SESSION_GAP_S` apart belong to different sessions (a log of several days is several sessions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import MapError
from vrsim.maps.crs import transform_xy, utm_crs_for
from vrsim.maps.pointlog import PointLog

__all__ = ["MachineRecords", "machine_records", "SESSION_GAP_S", "SPEED_SMOOTH_S"]

SESSION_GAP_S = 60.0       # records further apart than this belong to different sessions
SPEED_SMOOTH_S = 1.0       # speeds from distances are averaged over this window
MAX_SECTIONS = 64          # ISO 11783 condensed work states go to 16 x 16; 64 as AgOpenGPS's sections
WIDTH_STEP_TOLERANCE = 0.02   # distinct widths closer than this share of the widest are one width
REGULAR_JITTER = 0.1       # intervals this close to the median one are the logger's regular period


@dataclass
class MachineRecords:
    """A log's records, one row per timestamp (see the module docstring); rates in `unit`.

    Attributes
    ----------
    time_s : ndarray, shape (n,)
        Seconds since the log's first record, increasing.
    x_m, y_m : ndarray, shape (n,)
        The machine's centre in `crs` (a metric CRS: the log's UTM zone), m.
    heading_rad : ndarray, shape (n,)
        Heading, math convention (counter-clockwise from east), unwrapped.
    speed_m_s : ndarray, shape (n,)
        Ground speed, m/s.
    sections_on : ndarray of bool, shape (n, sections)
        Which sections were open, left to right.
    section_widths_m, section_offsets_m : ndarray, shape (sections,)
        Each section's width and its centre's offset left of the machine's centre, m.
    target, applied : ndarray, shape (n,)
        The logged target and applied rate (the open sections' mean, by width), in `unit`; NaN: none.
    session : ndarray of int, shape (n,)
        Which session each row is of, from 0.
    crs : pyproj.CRS
    unit : str
    per_section : bool
        Whether the log had a record per section per timestamp.
    source : str
    """

    time_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    speed_m_s: np.ndarray
    sections_on: np.ndarray
    section_widths_m: np.ndarray
    section_offsets_m: np.ndarray
    target: np.ndarray
    applied: np.ndarray
    session: np.ndarray
    crs: object
    unit: str
    per_section: bool
    source: str

    @property
    def rows(self) -> int:
        return int(self.time_s.size)

    @property
    def sessions(self) -> int:
        return int(self.session.max()) + 1 if self.session.size else 0

    @property
    def width_on_m(self) -> np.ndarray:
        return self.sections_on @ self.section_widths_m

    def take(self, keep: np.ndarray) -> MachineRecords:
        """These records' rows `keep` (a bool mask or indices)."""
        out = {name: getattr(self, name)[keep] for name in ROW_FIELDS}
        return MachineRecords(**out, section_widths_m=self.section_widths_m,
                              section_offsets_m=self.section_offsets_m, crs=self.crs, unit=self.unit,
                              per_section=self.per_section, source=self.source)


ROW_FIELDS = ("time_s", "x_m", "y_m", "heading_rad", "speed_m_s", "sections_on", "target", "applied",
              "session")


def machine_records(log: PointLog) -> MachineRecords:
    """The records of `log` as rows per timestamp (see the module docstring).

    Raises
    ------
    MapError
        A log with no times, no positions or no applied rate, or records out of time order, naming the
        file, the field and the value.
    """
    where = log.source or "log"
    t = np.asarray(log.time_s, float)
    if not log.points:
        raise MapError(f"{where}: the log has no records")
    if not np.isfinite(t).all():
        bad = int(np.argmin(np.isfinite(t)))
        raise MapError(f"{where}: record {bad}: time is missing; a replay needs every record's time")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise MapError(f"{where}: record {i}: time {t[i]:.3f} s is before record {i - 1}'s {t[i - 1]:.3f} s; "
                       "records must be in time order")
    for name in ("x", "y", "applied"):
        values = getattr(log, name)
        if not np.isfinite(values).any():
            what = "an applied rate" if name == "applied" else "a position"
            raise MapError(f"{where}: no record has {what}")
    times, row = np.unique(t, return_inverse=True)
    per_section = times.size < t.size and (log.section_id >= 0).all()
    if per_section:
        sections_on, widths, offsets, x, y = _per_section(log, row, times.size)
    else:
        if times.size < t.size:
            i = int(np.argmax(np.diff(t) == 0)) + 1
            raise MapError(f"{where}: record {i} has the time of record {i - 1} ({t[i]:.3f} s) but no "
                           "section of its own (no SECTIONID): a log has one record per time, or one per "
                           "section")
        sections_on, widths = _sections_from_widths(log, where)
        offsets = _offsets(widths)
        x, y = log.x, log.y
    lon0, lat0 = _centre_lonlat(log)
    crs = utm_crs_for(lon0, lat0) if log.crs.is_geographic else log.crs
    xm, ym = transform_xy(x, y, log.crs, crs)
    xm, ym = np.asarray(xm, float), np.asarray(ym, float)
    heading = _first_per_row(log.heading_deg, row, times.size)
    applied = _width_mean(log.applied, log, row, times.size)
    target = _width_mean(log.target, log, row, times.size)
    distance = _first_per_row(log.distance_m, row, times.size)
    speed = _first_per_row(log.speed_m_s, row, times.size)
    session = np.concatenate(([0], np.cumsum(np.diff(times) > SESSION_GAP_S)))
    speed = _speed(times, xm, ym, speed, distance, session)
    heading_rad = _heading(heading, xm, ym, session)
    return MachineRecords(times, xm, ym, heading_rad, speed, sections_on, widths, offsets, target, applied,
                          session, crs, log.unit, bool(per_section), where)


def _per_section(log: PointLog, row: np.ndarray, rows: int):
    ids, col = np.unique(log.section_id, return_inverse=True)
    if ids.size > MAX_SECTIONS:
        raise MapError(f"{log.source}: SECTIONID: {ids.size} sections; vrsim replays at most {MAX_SECTIONS}")
    on = np.zeros((rows, ids.size), dtype=bool)
    on[row, col] = True
    width = log.width_m
    if not np.isfinite(width).any():
        raise MapError(f"{log.source}: a per-section log needs each record's width (SWATHWIDTH)")
    widths = np.array([np.nanmedian(width[col == c]) for c in range(ids.size)])
    # The machine's centre per timestamp: its sections' points weighted by width, then each section's
    # offset across the heading (left positive) from its records where every section is open.
    wsum = np.bincount(row, weights=np.nan_to_num(width), minlength=rows)
    x = np.bincount(row, weights=log.x * np.nan_to_num(width), minlength=rows) / wsum
    y = np.bincount(row, weights=log.y * np.nan_to_num(width), minlength=rows) / wsum
    full = on.all(axis=1)[row]
    hdg = np.radians(np.nan_to_num(log.heading_deg))
    # Offsets in the log's CRS units; a geographic CRS is scaled to metres locally.
    sx, sy = _metres_per_unit(log)
    left = (-(log.x - x[row]) * sx * np.cos(hdg) + (log.y - y[row]) * sy * np.sin(hdg))
    offsets = np.array([np.median(left[(col == c) & full]) if ((col == c) & full).any() else np.nan
                        for c in range(ids.size)])
    if np.isfinite(offsets).all():
        order = np.argsort(-offsets)   # left to right
    else:
        order = np.arange(ids.size)
    widths, on = widths[order], on[:, order]
    return on, widths, _offsets(widths), x, y


def _metres_per_unit(log: PointLog) -> tuple[float, float]:
    if not log.crs.is_geographic:
        return 1.0, 1.0
    lat = np.radians(np.nanmedian(log.y))
    return 111_320.0 * np.cos(lat), 110_540.0


def _sections_from_widths(log: PointLog, where: str):
    """Sections of a log of whole-machine records (see the module docstring)."""
    if log.sections_on.shape[1]:
        on = log.sections_on
        width = np.nanmax(log.width_m) if np.isfinite(log.width_m).any() else np.nan
        if not np.isfinite(width):
            raise MapError(f"{where}: the log has section states but no working width")
        widths = np.full(on.shape[1], width / on.shape[1])
        return on, widths
    width = log.width_m
    if not np.isfinite(width).any():
        raise MapError(f"{where}: the log gives no working width (SWATHWIDTH, width_m): give the machine "
                       "with --scenario or --machine")
    full = float(np.nanmax(width))
    distinct = np.unique(width[np.isfinite(width) & (width > 0)])
    # Widths within the tolerance of the next wider one are that width (rounding in the log).
    keep = np.concatenate((np.diff(distinct) > WIDTH_STEP_TOLERANCE * full, [True]))
    levels = distinct[keep]
    if levels.size > MAX_SECTIONS:
        levels = np.linspace(0, full, MAX_SECTIONS + 1)[1:]
    widths = np.diff(np.concatenate(([0.0], levels)))
    cum = np.cumsum(widths)
    reach = np.nan_to_num(width)[:, None] + 0.5 * WIDTH_STEP_TOLERANCE * full
    on = (cum[None, :] <= reach) & log.work_on[:, None]
    return on, widths


def _offsets(widths: np.ndarray) -> np.ndarray:
    """Section centres' offsets left of the machine's centre, sections left to right, m."""
    edges = widths.sum() / 2 - np.concatenate(([0.0], np.cumsum(widths)))
    return (edges[:-1] + edges[1:]) / 2


def _centre_lonlat(log: PointLog) -> tuple[float, float]:
    ok = np.isfinite(log.x) & np.isfinite(log.y)
    lon, lat = transform_xy(np.array([np.median(log.x[ok])]), np.array([np.median(log.y[ok])]), log.crs,
                            "EPSG:4326")
    return float(np.asarray(lon)[0]), float(np.asarray(lat)[0])


def _first_per_row(values: np.ndarray, row: np.ndarray, rows: int) -> np.ndarray:
    out = np.full(rows, np.nan)
    first = np.unique(row, return_index=True)[1]
    out[row[first]] = values[first]
    return out


def _width_mean(values: np.ndarray, log: PointLog, row: np.ndarray, rows: int) -> np.ndarray:
    """Per timestamp: the records' mean of `values` weighted by width (a plain mean without widths)."""
    w = np.where(np.isfinite(log.width_m), log.width_m, 1.0) * np.isfinite(values)
    total = np.bincount(row, weights=w, minlength=rows)
    s = np.bincount(row, weights=np.nan_to_num(values) * w, minlength=rows)
    return np.divide(s, total, out=np.full(rows, np.nan), where=total > 0)


def _speed(t, x, y, speed, distance, session) -> np.ndarray:
    """Ground speed per row, m/s, averaged over `SPEED_SMOOTH_S` (a logged speed's resolution steps and
    a distance's jitter would each move the target flow): from the log's speed, else its distance over
    the logger's period, else the positions."""
    dt = np.diff(t, prepend=np.nan)
    new = np.concatenate(([True], session[1:] != session[:-1]))
    dt = np.where(new | ~np.isfinite(dt), 0.0, dt)
    step = np.median(dt[dt > 0]) if (dt > 0).any() else SPEED_SMOOTH_S
    # A machine logs at a regular period and stamps its records with a few ms of jitter (a 5 Hz
    # export's 0.195 and 0.204 s, with the same distance each): the distance is over the period.
    dt = np.where(np.abs(dt - step) <= REGULAR_JITTER * step, step, dt)
    logged = np.isfinite(speed)
    if logged.all():
        d = speed * dt
    elif np.isfinite(distance).sum() > 0.9 * distance.size:
        d = np.where(np.isfinite(distance), distance, 0.0)
    else:
        d = np.hypot(np.diff(x, prepend=x[0]), np.diff(y, prepend=y[0]))
    d = np.where(new, 0.0, d)
    one = np.where(dt > 0, d / np.where(dt > 0, dt, 1.0), 0.0)
    alone = np.where(logged, speed, one)   # a row with no neighbour in its window
    out = np.empty_like(t)
    half_s = max(SPEED_SMOOTH_S, 2.5 * step) / 2
    for s in np.unique(session):   # distance over time, both summed over the window
        idx = np.flatnonzero(session == s)
        cd, ct, tt = np.cumsum(d[idx]), np.cumsum(dt[idx]), t[idx]
        lo = np.searchsorted(tt, tt - half_s, side="left")
        hi = np.searchsorted(tt, tt + half_s, side="right") - 1
        lo = np.minimum(lo, hi)
        span = ct[hi] - ct[lo]
        out[idx] = np.where(span > 0, (cd[hi] - cd[lo]) / np.where(span > 0, span, 1.0), alone[idx])
    return out


def _heading(heading_deg, x, y, session) -> np.ndarray:
    """Heading per row, math convention, unwrapped: the log's compass heading, else the positions'."""
    if np.isfinite(heading_deg).all():
        h = np.radians(90.0 - heading_deg)
    else:
        h = np.arctan2(np.diff(y, append=y[-1]), np.diff(x, append=x[-1]))
        h = np.where(np.isfinite(heading_deg), np.radians(90.0 - np.nan_to_num(heading_deg)), h)
    return np.unwrap(h)
