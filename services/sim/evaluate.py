"""How far a machine's as-applied log is from what it should have applied: `vrsim evaluate`'s pure core.

A log (`maps.PointLog`: a TASKDATA's TimeLogs, a John Deere point export, a run's own taskdata/) is
compared point by point either with the target rate it logged or with a prescription map looked up at
each point. Only records where the machine was applying to a target count (implement on, a
section on or a width above 0, a target above 0); the others are counted by reason (`EXCLUSIONS`).
Of those, records at a standstill (ground speed below a cut-off: the log's speed, else its distance,
else its positions', over time) are left out and counted, and outliers
(applied above a multiple of the target, `metrics.outliers`) counted and left out unless included.
The records are split into sessions where they are more than `SESSION_GAP_S` apart, as a replay's.
With ``delay_s``, the product metered at a record's time lands ``delay_s`` later, where
the machine is then (its position interpolated along the log at ``time_s + delay_s``): the applied
rate of the record is compared with the prescription there. The figures are `metrics.point_metrics`
(what each means: `metrics.POINT_METRICS`), weighted by each record's area (DISTANCE x width) where the
log gives both.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vrsim.common import MapError
from vrsim.maps import Grid, PointLog, grid_from_bounds, utm_crs_for
from vrsim.maps.crs import WGS84, transform_xy
from vrsim.maps.log_records import SESSION_GAP_S
from vrsim.maps.units import base_unit, convert_rate, is_rate_unit, rate_unit
from vrsim.services.sim.metrics import (
    OUTLIER_MULTIPLE,
    POINT_METRICS,
    STANDSTILL_M_S,
    LogScreen,
    PointMetrics,
    outliers,
    point_metrics,
)

ERROR_CELL_M = 5.0  # cell of the error map without a prescription: about a point's spacing at 1 Hz
MAX_DELAY_S = 30.0  # as `vehicle.Implement.delivery_delay_s`
# Why a record is not compared, in the order it is asked (a record counts under the first that holds).
EXCLUSIONS = ("implement_off", "no_section_on", "target_0", "no_applied_rate", "no_target",
              "outside_field")


@dataclass
class Evaluation:
    """A log compared with its targets.

    Attributes
    ----------
    log : maps.PointLog
        The log, its rates in `unit`.
    unit : str
        Unit of every rate figure.
    against : str
        ``"logged target"`` or the prescription's source.
    target : ndarray, shape (n,)
        What each point's applied rate is compared with.
    compared : ndarray of bool, shape (n,)
        The points the figures are over: not excluded (`excluded`), not at a standstill and, unless
        included, not outliers.
    x_m, y_m : ndarray, shape (n,)
        Where each point is compared, in `crs` (metres; with a delay, where its product landed; NaN
        without a position).
    distance_m : ndarray, shape (n,)
        Distance travelled along the logged positions up to each point.
    delay_s : float
    metrics : PointMetrics
    excluded : dict of str -> int
        Records not compared, by reason (`EXCLUSIONS`; each record under its first reason).
    speed_m_s : ndarray, shape (n,)
        Each record's ground speed (NaN: not known).
    standstill, outlier : ndarray of bool, shape (n,)
        The records otherwise compared that were at a standstill, and the outliers among the rest.
    session : ndarray of int, shape (n,)
        Each record's session, from 0 in time order (records without a time: 0).
    """

    log: PointLog
    unit: str
    against: str
    target: np.ndarray
    compared: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    crs: object
    distance_m: np.ndarray
    delay_s: float
    metrics: PointMetrics
    excluded: dict
    speed_m_s: np.ndarray
    standstill: np.ndarray
    outlier: np.ndarray
    session: np.ndarray

    def summary(self) -> dict:
        """``points``, ``unit``, the other `POINT_METRICS` figures, then ``excluded`` (records left out,
        by reason): the JSON `vrsim evaluate` prints."""
        figures = dataclasses.asdict(self.metrics)
        return {"points": figures["points"], "unit": self.unit,
                **{m.key: figures[m.key] for m in POINT_METRICS if m.key != "points"},
                "excluded": dict(self.excluded)}


def evaluate(log: PointLog, prescription: Grid | None = None, field=None, delay_s: float = 0.0,
             include_zero_target: bool = False, density_kg_l: float | None = None,
             standstill_m_s: float = STANDSTILL_M_S, outlier_multiple: float = OUTLIER_MULTIPLE,
             include_outliers: bool = False) -> Evaluation:
    """Compare a log's applied rates with its logged targets, or with `prescription` at each point.

    Parameters
    ----------
    log : maps.PointLog
        Its `unit` must be a rate unit (`maps.units.rate_unit`).
    prescription : maps.Grid, optional
        Looked up at each point (at the point ``delay_s`` later); the log is compared with it in the
        map's own unit (`Grid.map_unit`), converted to it (a volume rate against a mass rate map with
        the product's density).
    field : vehicle.Field, optional
        Only points inside its boundary are compared.
    delay_s : float
        Delivery delay from meter to ground, s (>= 0): see the module docstring.
    include_zero_target : bool
        Also compare records whose target is 0 (or below): the machine was told not to apply there.
    density_kg_l : float, optional
        The product's density, kg/L (default: the one `prescription` was read with).
    standstill_m_s : float
        Records at a ground speed below this (m/s, >= 0; 0: none) are left out and counted.
    outlier_multiple : float
        Records applying more than this many times their target (> 1) are outliers: counted, and left
        out unless `include_outliers`.
    include_outliers : bool
        Keep the outliers in the figures.

    Raises
    ------
    MapError
        Naming the log: a unit it does not say or that does not convert, a delay without times, a
        cut-off out of range, no point to compare.
    """
    where = log.source or "log"
    if not is_rate_unit(log.unit):
        raise MapError(f"{where}: the unit of its rates is {log.unit or 'not stated'!r}; give it with --unit "
                       "(kg/ha, lb/ac, L/ha, gal/ac, ...)")
    log = dataclasses.replace(log, unit=rate_unit(log.unit))
    if not (isinstance(delay_s, (int, float)) and math.isfinite(delay_s) and 0 <= delay_s <= MAX_DELAY_S):
        raise MapError(f"--delay-s {delay_s!r}: must be a number from 0 to {MAX_DELAY_S:g} s")
    _check_cut_offs(standstill_m_s, outlier_multiple)
    if prescription is not None:
        density = prescription.density_kg_l if density_kg_l is None else density_kg_l
        try:
            log = log.in_unit(prescription.map_unit, density)
        except MapError as exc:
            raise MapError(f"{where}: cannot compare with the prescription {prescription.source} "
                           f"({prescription.map_unit}): {exc}"
                           f"{'; give it with --density-kg-l' if 'density' in str(exc) else ''}") from None
    x_m, y_m, crs = _metric_positions(log)
    lx, ly = _delayed(log, x_m, y_m, delay_s, where)
    if prescription is not None:
        target = prescription.in_map_unit(prescription.lookup(lx, ly, crs=crs).rate_kg_ha)
        against = prescription.source or "prescription"
    else:
        target = log.target
        against = "logged target"
    inside = np.ones(log.points, dtype=bool)
    if field is not None:
        fx, fy = transform_xy(lx, ly, crs, field.crs)
        import shapely

        inside = shapely.contains_xy(field.polygon, fx, fy)
    valid, excluded = _select(log, target, inside, include_zero_target)
    speed, speed_from = _speed_m_s(log, x_m, y_m)
    with np.errstate(invalid="ignore"):  # a speed not known is not a standstill
        standstill = valid & (speed < standstill_m_s)
    outlier = valid & ~standstill & outliers(log.applied, target, outlier_multiple)
    compared = valid & ~standstill & (~outlier | include_outliers)
    if not compared.any():
        _nothing_to_compare(log, excluded, int(standstill.sum()), int((outlier & ~compared).sum()),
                            prescription is not None, field is not None)
    distance = distance_along_m(x_m, y_m)
    time_s = np.where(np.isfinite(log.time_s), log.time_s, np.arange(log.points, dtype=float))
    scale = float(convert_rate(1.0, log.unit, base_unit(log.unit)))
    session = _sessions(log.time_s)
    screen = LogScreen(int(standstill.sum()), float(standstill_m_s), speed_from, int(outlier.sum()),
                       float(outlier_multiple), bool(include_outliers), int(session.max()) + 1)
    figures = point_metrics(log.applied, target, time_s, distance, compared, step_scale=scale,
                            area_m2=log.distance_m * log.width_m, screen=screen)
    return Evaluation(log, log.unit, against, np.asarray(target, float), compared, lx, ly, crs, distance,
                      float(delay_s), figures, excluded, speed, standstill, outlier, session)


def _check_cut_offs(standstill_m_s, outlier_multiple) -> None:
    """Refuse a standstill cut-off or an outlier multiple that is not a number in its range."""
    def number(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if not (number(standstill_m_s) and standstill_m_s >= 0):
        raise MapError(f"--standstill-m-s {standstill_m_s!r}: must be a speed of 0 m/s or more")
    if not (number(outlier_multiple) and outlier_multiple > 1):
        raise MapError(f"--outlier-multiple {outlier_multiple!r}: must be a number above 1 (times the "
                       "target)")


def _nothing_to_compare(log: PointLog, excluded: dict, standstill: int, outlier: int, on_map: bool,
                        in_field: bool):
    """Raise the MapError of a log with no point to compare, saying what was left out."""
    reasons = {**excluded, "at a standstill": standstill, "outliers": outlier}
    left = ", ".join(f"{n} {r.replace('_', ' ')}" for r, n in reasons.items() if n)
    raise MapError(f"{log.source or 'log'}: no point to compare ({log.points} records; none with the "
                   f"implement on, an applied rate and a target{' on the map' if on_map else ''}"
                   f"{' inside the field' if in_field else ''}; left out: {left})")


def _speed_m_s(log: PointLog, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, str]:
    """Each record's ground speed, m/s, and where it is from: the log's speed, else its distance, else
    its positions' (the centre of a timestamp's records), over the time since the previous timestamp;
    NaN where not known (no time; positions at a session's first timestamp).

    Chosen in `maps.log_records`' order, but not smoothed over 1 s as it is for a replay's drive: a
    record's rate is over its own interval, so each record of a stop counts by its own speed.
    """
    logged = np.isfinite(log.speed_m_s)
    if logged.all():
        return log.speed_m_s, "logged speed"
    ok = np.isfinite(log.time_s)
    times, row = np.unique(log.time_s[ok], return_inverse=True)
    gap_s = np.diff(times, prepend=np.nan)
    first = ~(gap_s <= SESSION_GAP_S)  # a session's first timestamp: no previous one to go from
    if np.isfinite(log.distance_m).sum() > 0.9 * log.points:  # as `maps.log_records` chooses
        # A logger's DISTANCE is over its period, which a session's first record has too.
        period_s = np.median(gap_s[~first]) if (~first).any() else np.nan
        per_time, source = 1.0 / np.where(first, period_s, gap_s), "distance over time"
        speed = np.full(log.points, np.nan)
        speed[ok] = log.distance_m[ok] * per_time[row]
    else:
        count = np.bincount(row, minlength=times.size)
        cx, cy = (np.bincount(row, weights=v[ok], minlength=times.size) / count for v in (x_m, y_m))
        step = np.hypot(np.diff(cx, prepend=np.nan), np.diff(cy, prepend=np.nan)) / gap_s
        per_time, source = np.where(first, np.nan, step), "positions over time"
        speed = np.full(log.points, np.nan)
        speed[ok] = per_time[row]
    if logged.any():
        return np.where(logged, log.speed_m_s, speed), f"logged speed, else {source}"
    return speed, source if ok.any() else "not known"


def _sessions(time_s: np.ndarray) -> np.ndarray:
    """Each record's session, from 0: in time order, records more than `SESSION_GAP_S` apart begin a new
    one, as `maps.log_records` splits a log for a replay; records without a time are of session 0."""
    ok = np.isfinite(time_s)
    times, row = np.unique(time_s[ok], return_inverse=True)
    per_time = np.concatenate(([0], np.cumsum(np.diff(times) > SESSION_GAP_S)))
    session = np.zeros(time_s.size, dtype=np.int64)
    session[ok] = per_time[row]
    return session


def _section_on(log: PointLog) -> np.ndarray:
    """Records with a section on (where the log has section states), else with a working width above 0
    (where it logs one; a width not logged does not exclude)."""
    if log.sections_on.shape[1]:
        return log.sections_on.any(axis=1)
    return ~(log.width_m <= 0)


def _select(log: PointLog, target, inside, include_zero_target: bool):
    """(compared, excluded): the records compared and the others counted by their first `EXCLUSIONS`."""
    with np.errstate(invalid="ignore"):
        keep = {"implement_off": log.work_on, "no_section_on": _section_on(log),
                "target_0": ~(target <= 0) | include_zero_target, "no_applied_rate": np.isfinite(log.applied),
                "no_target": np.isfinite(target), "outside_field": np.asarray(inside, bool)}
    compared = np.ones(log.points, dtype=bool)
    excluded = {}
    for reason in EXCLUSIONS:
        out = compared & ~keep[reason]
        excluded[reason] = int(out.sum())
        compared &= keep[reason]
    return compared, excluded


def _metric_positions(log: PointLog):
    """Positions in the UTM zone of the log's median point (metres), and that CRS."""
    lon, lat = log.lonlat()
    ok = np.isfinite(lon) & np.isfinite(lat)
    if not ok.any():
        raise MapError(f"{log.source or 'log'}: no record has a position")
    crs = utm_crs_for(float(np.median(lon[ok])), float(np.median(lat[ok])))
    x, y = transform_xy(lon, lat, WGS84, crs)
    return np.where(ok, x, np.nan), np.where(ok, y, np.nan), crs


def _delayed(log: PointLog, x_m, y_m, delay_s: float, where: str):
    """Where each record's product lands: the position `delay_s` later along the log (NaN past its end)."""
    if delay_s == 0:
        return x_m, y_m
    ok = np.isfinite(log.time_s) & np.isfinite(x_m)
    if ok.sum() < 2:
        raise MapError(f"{where}: --delay-s needs the records' times and positions; the log has "
                       f"{int(ok.sum())} record(s) with both")
    t = log.time_s[ok]
    at = log.time_s + delay_s
    return (np.interp(at, t, x_m[ok], left=np.nan, right=np.nan),
            np.interp(at, t, y_m[ok], left=np.nan, right=np.nan))


def distance_along_m(x_m, y_m) -> np.ndarray:
    """Distance travelled up to each point along the logged positions (a gap adds nothing)."""
    step = np.hypot(np.diff(x_m), np.diff(y_m))
    return np.concatenate(([0.0], np.cumsum(np.where(np.isfinite(step), step, 0.0))))


def error_grid(ev: Evaluation, prescription: Grid | None = None, cell_m: float = ERROR_CELL_M) -> Grid:
    """Applied minus target per cell, the mean over the points compared in it (cells without one:
    nodata), on the prescription's grid, else on a grid of `cell_m` over the points (UTM)."""
    if prescription is not None:
        geometry = prescription
        found = prescription.lookup(ev.x_m, ev.y_m, crs=ev.crs)
        row, col = found.row, found.col
    else:
        x, y = ev.x_m[ev.compared], ev.y_m[ev.compared]
        pad = cell_m / 2
        geometry = grid_from_bounds((x.min() - pad, y.min() - pad, x.max() + pad, y.max() + pad), cell_m,
                                    ev.crs)
        col = np.floor((ev.x_m - geometry.transform.c) / cell_m)
        row = np.floor((geometry.transform.f - ev.y_m) / cell_m)
        row, col = (np.where(np.isfinite(v), v, -1).astype(np.int64) for v in (row, col))
    use = ev.compared & (row >= 0) & (col >= 0) & (row < geometry.rows) & (col < geometry.cols)
    cell = row[use] * geometry.cols + col[use]
    size = geometry.rows * geometry.cols
    total = np.bincount(cell, weights=ev.log.applied[use] - ev.target[use], minlength=size)
    count = np.bincount(cell, minlength=size)
    mean = np.divide(total, count, out=np.full(size, np.nan), where=count > 0)
    return Grid(mean.reshape(geometry.rows, geometry.cols), geometry.transform, geometry.crs,
                product=f"applied minus {ev.against if ev.against == 'logged target' else 'prescribed'}",
                source=ev.log.source, format="evaluation", unit=ev.unit, quantity="difference")
