"""Replay a real as-applied log through the simulator: the machine's own drive, the simulated machine.

A log becomes a drive (`maps.log_records`): its timestamps, positions, heading, ground speed, each
section's state and the target it was given (the log's own, or a prescription's at each position).
The control core a field run uses (`services.sim.core.ControlCore.run_states`: the machine kind's
targets, its loop, its metering; the scenario's ``[response]``) runs that drive tick by tick, and the
simulated rate is read at the log's own timestamps as the machine logs it: its flow meter's reading
(the loop plant's sensor delay, the dead time included) over the ground the open sections cover at
the logged speed, averaged over the ticks since the previous record, in the log's unit. A session
whose first record shows the machine settled on its target began mid-pass (a log cut or resumed): the
machine runs in at that record's state for `LEAD_IN_S` first; otherwise it starts at rest a logging
period before its first record (whose rate is that period's), and its first record is a pass start.

The figures compare the twin with the log (``*_vs_log``) beside the same figures of the target as the
prediction (``target_*_vs_log``: what a twin must beat), over all the records that count and per event
class (`EVENT_CLASSES`), so a user sees where the twin misses. Records below `STANDSTILL_M_S` and
records with every section closed do not count; they are counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim.common import ScenarioError
from vrsim.maps import Grid
from vrsim.maps.crs import transform_xy
from vrsim.maps.grid import grid_from_bounds
from vrsim.maps.log_records import MachineRecords
from vrsim.maps.units import base_unit, convert_rate, rate_kind
from vrsim.services.sim.core import ControlCore, machine_plant
from vrsim.services.sim.evaluate import distance_along_m
from vrsim.services.sim.metrics import STANDSTILL_M_S  # the cut-off `vrsim evaluate` leaves records out by
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.sections.motion import MotionTrend
from vrsim.services.sim.transitions import EVENTS, transitions

__all__ = ["EVENT_CLASSES", "Replay", "compare_to_log", "event_figures", "figures", "replay_records",
           "working_point_grid"]

EVENT_WINDOW_S = 8.0        # a record this soon after an event belongs to its class
RATE_STEP_FRACTION = 0.02   # a target change larger than this share is a rate step
MIN_SESSION_S = 3.0         # a session shorter than this cannot be replayed
SETTLED_FRACTION = 0.1      # a first record this close to its target: the machine was already running
LEAD_IN_S = 30.0            # ... and runs in this long at that record's state before it
EVENT_CLASSES = ("pass_start", "rate_step", "section_change", "steady")


@dataclass
class Replay:
    """A replayed log: the records, what the twin logged at their timestamps, and the figures.

    Attributes
    ----------
    records : maps.log_records.MachineRecords
        The log's records (rows per timestamp) that were replayed.
    simulated : ndarray, shape (n,)
        The twin's applied rate at each record, in ``records.unit``; NaN where nothing was open.
    event : ndarray of str, shape (n,)
        Each record's event class (`EVENT_CLASSES`).
    counts : ndarray of bool, shape (n,)
        Whether the record counts in the figures (moving, some section open, a logged applied rate).
    summary : dict
        The figures (`figures`), with ``standstill_records``, ``closed_records`` and ``sessions``.
    """

    records: MachineRecords
    simulated: np.ndarray
    event: np.ndarray
    counts: np.ndarray
    summary: dict


def replay_records(records: MachineRecords, scenario: Scenario) -> Replay:
    """Replay `records` with the machine of `scenario` (its implement's sections must be the log's:
    `services.sim.replay_setup.replay_scenario` makes such a scenario). Each session runs on its own
    machine, at rest at its start."""
    if records.unit and rate_kind(records.unit) == "volume" and scenario.product.density_kg_l is None:
        raise ScenarioError(f"{scenario.source}: [product] density_kg_l: the log's rates are a volume "
                            f"({records.unit}); give the product's density")
    simulated = np.full(records.rows, np.nan)
    for s in range(records.sessions):
        rows = np.flatnonzero(records.session == s)
        simulated[rows] = _session(records.take(rows), scenario)
    event = _event_classes(records)
    counts = _counting(records)
    summary = figures(records.applied, simulated, records.target, event, counts)
    summary.update(event_figures(records, simulated, counts, scenario.product.density_kg_l))
    summary.update(sessions=records.sessions, records=records.rows,
                   standstill_records=int((records.speed_m_s < STANDSTILL_M_S).sum()),
                   closed_records=int((~records.sections_on.any(axis=1)).sum()), rate_unit=records.unit)
    return Replay(records, simulated, event, counts, summary)


def _session(rec: MachineRecords, scenario: Scenario) -> np.ndarray:
    """The twin's applied rate at each record of one session, in the log's unit."""
    duration_s = rec.time_s[-1] - rec.time_s[0]
    if duration_s < MIN_SESSION_S:
        raise ScenarioError(f"{rec.source}: a session of {duration_s:.1f} s from {rec.time_s[0]:.1f} s is "
                            f"shorter than {MIN_SESSION_S:g} s: too short to replay (choose another session)")
    period_s = scenario.timing.control_period_s
    # A record's rate is the mean of the interval before it, so the sections were open a logging period
    # before the first record; a session that begins settled began before that: the machine runs in at
    # the first record's state first (np.interp holds the first record's values before it).
    lead_s = LEAD_IN_S if _settled_at_start(rec)[0] else float(np.median(np.diff(rec.time_s)))
    t = rec.time_s[0] - lead_s + period_s * np.arange(math.ceil((duration_s + lead_s) / period_s) + 1)
    prev = np.clip(np.searchsorted(rec.time_s, t, side="right") - 1, 0, rec.rows - 1)
    x, y = (np.interp(t, rec.time_s, a) for a in (rec.x_m, rec.y_m))
    heading = np.interp(t, rec.time_s, rec.heading_rad)
    speed = np.interp(t, rec.time_s, rec.speed_m_s)
    on = rec.sections_on[prev]
    density = scenario.product.density_kg_l
    rate_kg_ha = convert_rate(rec.target[prev], rec.unit or "kg/ha", "kg/ha", density)
    core = ControlCore(working_point_grid(rec, rate_kg_ha), scenario, None)
    motion = MotionTrend(period_s).step(x, y, heading, speed)
    opened = on.any(axis=1) & ~np.concatenate(([False], on.any(axis=1)[:-1]))
    pass_index = np.where(on.any(axis=1), np.cumsum(opened) - 1, -1)
    states = SectionStates(on, rec.section_widths_m, rec.section_offsets_m, pass_index, on, motion)
    rates = np.broadcast_to(np.nan_to_num(rate_kg_ha)[:, None], (t.size, core.machine.drives))
    control = core.run_states(states, rates)
    # The machine logs its reading: the flow the loop measures, the sensor delay (and dead time) late.
    delay_s = machine_plant(scenario, core.grid, core.machine).sensor_delay_s
    kg_s = np.interp(t - delay_s, t, control["metered_kg"] / period_s, left=0.0)
    ground_m2_s = speed * states.width_on_m
    tick_kg_ha = np.divide(kg_s * 1e4, ground_m2_s, out=np.full(t.size, np.nan), where=ground_m2_s > 0)
    per_record = _per_record(t, tick_kg_ha, rec.time_s, period_s)
    return convert_rate(per_record, "kg/ha", rec.unit or "kg/ha", density)


def working_point_grid(rec: MachineRecords, rate_kg_ha: np.ndarray) -> Grid:
    """A one-cell prescription at the log's median positive target: the loop's working point."""
    positive = rate_kg_ha[np.isfinite(rate_kg_ha) & (rate_kg_ha > 0)]
    rate = float(np.median(positive)) if positive.size else 0.0
    x0, y0 = float(np.nanmedian(rec.x_m)), float(np.nanmedian(rec.y_m))
    return grid_from_bounds((x0 - 1, y0 - 1, x0 + 1, y0 + 1), 2.0, rec.crs, rates=np.full((1, 1), rate))


def _per_record(t: np.ndarray, tick_value: np.ndarray, record_s: np.ndarray, period_s: float) -> np.ndarray:
    """Each record's mean of the ticks since the previous record (the first: its own tick)."""
    k = np.clip(np.rint((record_s - t[0]) / period_s).astype(int), 0, t.size - 1)
    start = np.concatenate(([k[0]], k[:-1] + 1))
    start = np.minimum(start, k)
    ok = np.isfinite(tick_value)
    csum = np.concatenate(([0.0], np.cumsum(np.where(ok, tick_value, 0.0))))
    cnt = np.concatenate(([0], np.cumsum(ok)))
    n = cnt[k + 1] - cnt[start]
    return np.divide(csum[k + 1] - csum[start], n, out=np.full(k.size, np.nan), where=n > 0)


def _event_classes(rec: MachineRecords) -> np.ndarray:
    """Each record's event class: within `EVENT_WINDOW_S` after the sections opened from all closed
    (or a session began with them open) ``pass_start``; after the target changed by more than
    `RATE_STEP_FRACTION` ``rate_step``; after the open width changed ``section_change``; else ``steady``."""
    on = rec.sections_on.any(axis=1)
    width = rec.width_on_m
    new_session = np.concatenate(([True], rec.session[1:] != rec.session[:-1]))
    prev_on = np.concatenate(([False], on[:-1])) & ~new_session
    prev_on[new_session] = _settled_at_start(rec)   # a session that begins settled began mid-pass
    target = np.nan_to_num(rec.target)
    prev_target = np.concatenate(([target[0]], target[:-1]))
    events = {
        "pass_start": on & ~prev_on,
        "rate_step": ~new_session & (np.abs(target - prev_target) > RATE_STEP_FRACTION * np.abs(prev_target)),
        "section_change": ~new_session & prev_on & on & (np.abs(np.diff(width, prepend=width[0])) > 1e-6),
    }
    out = np.full(rec.rows, "steady", dtype=object)
    for name in reversed(EVENT_CLASSES[:-1]):   # the first class wins where windows overlap
        out[_within(rec.time_s, rec.session, events[name])] = name
    return out.astype(str)


def _settled_at_start(rec: MachineRecords) -> np.ndarray:
    """Per session: whether its first record shows the machine settled (a section open, the applied rate
    within `SETTLED_FRACTION` of the target): the log began mid-pass, not where the sections opened."""
    first = np.flatnonzero(np.concatenate(([True], rec.session[1:] != rec.session[:-1])))
    applied, target = rec.applied[first], rec.target[first]
    near = np.abs(applied - target) <= SETTLED_FRACTION * np.abs(target)
    return rec.sections_on[first].any(axis=1) & near & (target > 0)


def _within(t: np.ndarray, session: np.ndarray, event: np.ndarray) -> np.ndarray:
    """Records within `EVENT_WINDOW_S` after an event of their session."""
    idx = np.arange(t.size, dtype=float)
    last = np.maximum.accumulate(np.where(event, idx, -1.0)).astype(int)
    ok = last >= 0
    safe = np.where(ok, last, 0)
    return ok & (session[safe] == session) & (t - t[safe] < EVENT_WINDOW_S)


def _counting(rec: MachineRecords) -> np.ndarray:
    return (rec.speed_m_s >= STANDSTILL_M_S) & rec.sections_on.any(axis=1) & np.isfinite(rec.applied)


def figures(logged, simulated, target, event, counts) -> dict:
    """The twin's figures against the log and the target's, overall and per event class (``<figure>``
    and ``<class>_<figure>``; a class with no record counting gives None), and ``twin_mae_vs_target``."""
    keep = counts & np.isfinite(simulated)
    out = compare_to_log(logged, simulated, target, keep)
    # The twin's own error against its target, beside the machine's (``target_mae_vs_log``): what a
    # controller tuned on the twin is judged by.
    out["twin_mae_vs_target"] = float(np.mean(np.abs(simulated[keep] - target[keep]))) if keep.any() else None
    for name in EVENT_CLASSES:
        part = compare_to_log(logged, simulated, target, counts & np.isfinite(simulated) & (event == name))
        out.update({f"{name}_{k}": v for k, v in part.items()})
    return out


def event_figures(rec: MachineRecords, simulated, counts, density_kg_l=None) -> dict:
    """The transitions by event class (`services.sim.transitions.EVENTS`: rate steps, steps to zero,
    pass starts, pass ends) of the logged applied rate and of the twin's against the logged target, as
    `vrsim run` and `vrsim evaluate` count them over the records that count: ``log_<class>_<figure>`` and
    ``twin_<class>_<figure>`` for its events, mean time (s) and mean peak error (%)."""
    unit = rec.unit or "kg/ha"
    # A rate step means the same in any unit (5 kg/ha, or 5 L/ha).
    scale = float(convert_rate(1.0, unit, base_unit(unit), density_kg_l))
    distance = distance_along_m(rec.x_m, rec.y_m)
    out = {}
    for who, applied in (("log", rec.applied), ("twin", simulated)):
        use = counts & np.isfinite(applied)
        tm = transitions(rec.time_s, distance, rec.target * scale, applied * scale, use)
        for kind in EVENTS:
            part = getattr(tm, kind)
            out.update({f"{who}_{kind}_events": part.events, f"{who}_{kind}_time_s_mean": part.time_s_mean,
                        f"{who}_{kind}_peak_error_pct_mean": part.peak_error_pct_mean})
    return out


def compare_to_log(logged, simulated, target, keep) -> dict:
    twin, base = _vs_log(logged[keep], simulated[keep]), _vs_log(logged[keep], target[keep])
    return {"compared_records": int(keep.sum()), **twin, **{f"target_{k}": v for k, v in base.items()}}


def _vs_log(log: np.ndarray, pred: np.ndarray) -> dict:
    """How far prediction `pred` is from the logged rates `log` (the log's unit)."""
    if not log.size:
        return {k: None for k in ("mae_vs_log", "bias_vs_log", "rmse_vs_log", "r2_vs_log",
                                  "within_10pct_of_log_pct")}
    err = pred - log
    ss_tot = float(np.sum((log - log.mean()) ** 2))
    return {"mae_vs_log": float(np.mean(np.abs(err))), "bias_vs_log": float(np.mean(err)),
            "rmse_vs_log": float(np.sqrt(np.mean(err ** 2))),
            "r2_vs_log": 1.0 - float(np.sum(err ** 2)) / ss_tot if ss_tot > 0 else None,
            "within_10pct_of_log_pct": 100.0 * float(np.mean(np.abs(err) <= 0.1 * np.abs(log)))}


def lonlat(records: MachineRecords) -> tuple[np.ndarray, np.ndarray]:
    """The records' positions in WGS84 (for the outputs)."""
    lon, lat = transform_xy(records.x_m, records.y_m, records.crs, "EPSG:4326")
    return np.asarray(lon, float), np.asarray(lat, float)
