"""Accuracy metrics: how far the applied rate is from the prescribed one, on the map and in time.

Pure functions over numpy arrays; no I/O. The formulas are the ones the README states.

On the map (per grid cell, all cells of equal area ``cell_area_ha``):

- a cell is *covered* when its swept-area fraction is at least ``COVERED_FRACTION``; partly covered
  edge cells are left out of the error figures because their error is path geometry, not metering;
- error ``e = applied_kg_ha - prescribed_kg_ha`` over covered cells inside the field;
  ``mae = mean(|e|)``, ``rmse = sqrt(mean(e**2))``, ``bias = mean(e)``, and each also as % of the mean
  prescription over those cells;
- within +-p %: share of covered cells with a positive prescription where ``|e| <= p/100 * prescribed``;
- prescribed_kg: sum over cells inside the field of ``prescribed * cell_area_ha * min(coverage, 1)``,
  the product the prescription asks for on the area actually worked; applied_kg: all product metered;
  mass balance ``100 * (applied - prescribed) / prescribed``;
- off_target_kg: product landing outside the field or off the grid, plus product on zero-rate cells;
- coverage_pct: share of the field's cells that are covered.

Section control and the machine (see `overlap_metrics`, `limit_metrics`): overlap and skipped area,
product beyond the first pass, and the share of working time and covered area where the meter could
not turn at the speed the map asked for. In time (per tick, along the track): `transitions`.

`METRICS` is the one table of every figure a run reports: its key, unit, label and meaning, the
tolerance the accuracy library holds it to, and how it comes from a run's accounts
(`services.sim.accounting.Accounts`). The summary (`summary`: ``vrsim run`` and ``--json``, the
monitor's report, the variants of sweeps), the rows of the text and HTML reports and the accuracy
library's tolerances all derive from it, so a new figure is one row here and its formula.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from operator import attrgetter
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from services.sim.accounting import Accounts

COVERED_FRACTION = 0.9  # swept share of a cell's area above which it counts as covered
TRANSITION_TOLERANCE = 0.10  # "within 10 % of the new rate"
STEP_MIN_RELATIVE = 0.10  # a rate change of more than 10 % ...
STEP_MIN_KG_HA = 5.0  # ... and more than 5 kg/ha is a rate step


@dataclass(frozen=True)
class Metric:
    """One figure of a run's summary.

    Attributes
    ----------
    key : str
        Its key in the summary (``vrsim run --json``, summary.json, the monitor's report).
    unit : str
        Unit shown beside it ("" for a count).
    label : str
        Its row in the text and HTML reports; "" keeps it out of them.
    description : str
        What it measures, in one line.
    tolerance : (float, float) or None
        What the accuracy library holds it to: (absolute floor, share of the value); None for figures
        of the machine (timings) or of the set-up, not of the model.
    sense : {"min", "max", "zero"} or None
        Which way is better for the figures sweeps rank and `vrsim tune` optimizes: smaller, larger, or
        closest to zero (a bias, a mass balance); None for one that describes the run, not judges it.
    of : str or callable or None
        How its value comes from a run's `Accounts`: a dotted path of attributes (``"map.mae_kg_ha"``)
        or a formula, ``of(accounts) -> value``; None for a log's figures (`point_metrics`).
    """

    key: str
    unit: str
    label: str
    description: str
    tolerance: tuple[float, float] | None = None
    sense: str | None = None
    of: str | Callable[[Accounts], object] | None = None

    def value(self, accounts: Accounts):
        """This figure of a run (`of`)."""
        return self.of(accounts) if callable(self.of) else attrgetter(self.of)(accounts)


# Formulas of figures that are not one attribute of the accounts and serve more than one row.
def _sim_time_s(a: Accounts) -> float:
    return len(a.setting.track["time_s"]) * a.setting.world.scenario.timing.control_period_s


# The tolerances are chosen so that the run-to-run noise of a deterministic simulation (zero on one
# machine, last-digit differences across BLAS builds) passes and a change of the model or controller
# that a user would notice fails.
METRICS = (
    Metric("field_area_ha", "ha", "Field area", "area of the field boundary",
           of="setting.world.field.area_ha"),
    Metric("sim_time_s", "s", "Simulated time", "ticks x control period", of=_sim_time_s),
    Metric("wall_time_s", "s", "Wall time", "wall-clock time of the run (outputs not included)",
           of="timing.wall_time_s"),
    Metric("ticks", "", "", "control ticks driven", of=lambda a: len(a.setting.track["time_s"])),
    Metric("realtime_factor", "x", "Real-time factor", "simulated time over wall time",
           of=lambda a: _sim_time_s(a) / a.timing.wall_time_s),
    Metric("prescribed_kg", "kg", "Prescribed product",
           "what the prescription asks for on the area actually worked", (0.5, 0.005),
           of="map.prescribed_kg"),
    Metric("applied_kg", "kg", "Applied product", "all product metered", (0.5, 0.005), of="map.applied_kg"),
    Metric("mass_balance_pct", "%", "Mass balance", "100 (applied - prescribed) / prescribed", (0.3, 0.0),
           sense="zero", of="map.mass_balance_pct"),
    Metric("mae_kg_ha", "kg/ha", "Mean absolute error", "mean |applied - prescribed| over covered cells",
           (0.3, 0.03), sense="min", of="map.mae_kg_ha"),
    Metric("rmse_kg_ha", "kg/ha", "RMSE", "root mean square of applied - prescribed over covered cells",
           (0.3, 0.03), sense="min", of="map.rmse_kg_ha"),
    Metric("bias_kg_ha", "kg/ha", "Bias", "mean applied - prescribed over covered cells", (0.3, 0.03),
           sense="zero", of="map.bias_kg_ha"),
    Metric("within_5pct_area_pct", "%", "Covered area within +-5 %",
           "share of covered cells within 5 % of a positive prescription", (1.0, 0.0), sense="max",
           of="map.within_5pct_area_pct"),
    Metric("within_10pct_area_pct", "%", "Covered area within +-10 %",
           "share of covered cells within 10 % of a positive prescription", (1.0, 0.0), sense="max",
           of="map.within_10pct_area_pct"),
    Metric("transition_time_s_mean", "s", "Transition time, mean",
           "from a rate step until the applied rate is within 10 % of the new rate", (0.05, 0.05),
           sense="min", of="transitions.transition_time_s_mean"),
    Metric("transition_time_s_p95", "s", "Transition time, 95th percentile", "as above, 95th percentile",
           (0.05, 0.05), sense="min", of="transitions.transition_time_s_p95"),
    Metric("transition_distance_m_mean", "m", "Transition distance, mean",
           "distance along the landing path over the transition", (0.1, 0.05), sense="min",
           of="transitions.transition_distance_m_mean"),
    Metric("transition_distance_m_p95", "m", "Transition distance, 95th percentile",
           "as above, 95th percentile", (0.1, 0.05), sense="min", of="transitions.transition_distance_m_p95"),
    Metric("off_target_kg", "kg", "Off-target product",
           "product landing outside the field, off the grid or on zero-rate cells", (0.2, 0.03), sense="min",
           of="map.off_target_kg"),
    Metric("coverage_pct", "%", "Coverage", "share of the field's cells that are covered", (0.3, 0.0),
           sense="max", of="map.coverage_pct"),
    Metric("overlap_area_pct", "%", "Overlap area",
           "share of the covered field area that received product from more than one pass", (0.3, 0.03),
           sense="min", of="overlap.overlap_area_pct"),
    Metric("skip_area_pct", "%", "Skipped area",
           "share of the worked field area (swept by the working width along working stretches) that "
           "received no product", (0.3, 0.03), sense="min", of="overlap.skip_area_pct"),
    Metric("overlap_kg", "kg", "Overlap product", "product applied beyond the first pass, in the field",
           (0.2, 0.03), sense="min", of="overlap.overlap_kg"),
    Metric("limited_time_pct", "%", "Machine-limited time",
           "share of applying time with the target shaft speed clipped to [shaft_rpm_min, shaft_rpm_max]",
           (0.3, 0.03), sense="min", of="limits.limited_time_pct"),
    Metric("limited_area_pct", "%", "Machine-limited area",
           "share of the covered field area where product was metered with the target clipped", (0.3, 0.03),
           sense="min", of="limits.limited_area_pct"),
    Metric("sections", "", "Sections", "number of sections of the implement",
           of="setting.world.scenario.implement.sections"),
    Metric("section_widths_m", "m", "Section widths", "width of each section, left to right",
           of=lambda a: [float(w) for w in a.setting.world.scenario.implement.section_widths]),
    Metric("max_speed_m_s", "m/s", "Highest speed for the map",
           "highest working speed at which the meter can apply the map's highest rate over the full width",
           of="setting.check.max_speed_m_s"),
    Metric("mae_pct", "%", "", "mean absolute error over the mean prescription of the covered cells",
           sense="min", of="map.mae_pct"),
    Metric("rmse_pct", "%", "", "RMSE over the mean prescription of the covered cells", sense="min",
           of="map.rmse_pct"),
    Metric("bias_pct", "%", "", "bias over the mean prescription of the covered cells", sense="zero",
           of="map.bias_pct"),
    Metric("transitions", "", "", "rate steps whose transition settled", of="transitions.transitions"),
    Metric("covered_cells", "", "", "cells inside the field swept to at least 90 %", of="map.covered_cells"),
    Metric("path_length_m", "m", "", "length of the landing path",   # the last tick's distance; 0: no tick
           of=lambda a: float(a.setting.landing.distance_m[-1:].sum())),
)


def summary(accounts: Accounts) -> dict:
    """``scenario``, every `METRICS` figure in table order (`Metric.value`), ``seed``, ``stage_s``."""
    scenario = accounts.setting.world.scenario
    return {"scenario": scenario.name, **{m.key: m.value(accounts) for m in METRICS}, "seed": scenario.seed,
            "stage_s": accounts.timing.stage_s}


@dataclass(frozen=True)
class MapMetrics:
    prescribed_kg: float
    applied_kg: float
    mass_balance_pct: float
    mae_kg_ha: float
    rmse_kg_ha: float
    bias_kg_ha: float
    mae_pct: float
    rmse_pct: float
    bias_pct: float
    within_5pct_area_pct: float
    within_10pct_area_pct: float
    off_target_kg: float
    coverage_pct: float
    covered_cells: int


@dataclass(frozen=True)
class TransitionMetrics:
    transitions: int
    transition_time_s_mean: float
    transition_time_s_p95: float
    transition_distance_m_mean: float
    transition_distance_m_p95: float


def _pct(part: float, whole: float) -> float:
    return float(100.0 * part / whole) if whole > 0 else float("nan")


@dataclass(frozen=True)
class Errors:
    """Applied against target over paired values (map cells or logged points)."""

    mean_target: float
    mae: float
    rmse: float
    bias: float
    within_5pct_pct: float
    within_10pct_pct: float


def errors(applied, target) -> Errors:
    """``e = applied - target``: mean |e|, sqrt(mean e^2), mean e, and the share of the values with a
    positive target where |e| <= 5 % (10 %) of it; NaN for no values.

    Parameters
    ----------
    applied, target : ndarray, shape (n,)
        Paired values, finite.
    """
    err = applied - target
    nan = float("nan")
    positive = target > 0
    rel = np.abs(err[positive]) / target[positive]
    return Errors(
        mean_target=float(target.mean()) if err.size else nan,
        mae=float(np.abs(err).mean()) if err.size else nan,
        rmse=float(np.sqrt((err**2).mean())) if err.size else nan,
        bias=float(err.mean()) if err.size else nan,
        within_5pct_pct=_pct(np.count_nonzero(rel <= 0.05), rel.size),
        within_10pct_pct=_pct(np.count_nonzero(rel <= 0.10), rel.size),
    )


def map_metrics(prescribed_kg_ha, applied_kg_ha, coverage_fraction, in_field, cell_area_ha,
                applied_total_kg, off_grid_kg=0.0) -> MapMetrics:
    """Applied-versus-prescribed figures over a grid.

    Parameters
    ----------
    prescribed_kg_ha, applied_kg_ha, coverage_fraction : ndarray, shape (rows, cols)
        Prescription (NaN on nodata), applied product per cell area, and swept share of each cell.
    in_field : ndarray of bool, shape (rows, cols)
        Cells whose centre lies inside the field boundary.
    cell_area_ha : float
        Area of one cell, in hectares.
    applied_total_kg : float
        All product metered during the run (kg), wherever it landed.
    off_grid_kg : float
        Product that landed outside the grid (kg).
    """
    rx = np.asarray(prescribed_kg_ha, dtype=float)
    applied = np.asarray(applied_kg_ha, dtype=float)
    cover = np.asarray(coverage_fraction, dtype=float)
    field = np.asarray(in_field, dtype=bool)
    if not (rx.shape == applied.shape == cover.shape == field.shape):
        raise ValueError("prescribed, applied, coverage and in_field must have the same shape")
    rx0 = np.nan_to_num(rx, nan=0.0)
    covered = field & (cover >= COVERED_FRACTION) & np.isfinite(rx)
    e = errors(applied[covered], rx[covered])
    prescribed_kg = float((rx0[field] * np.minimum(cover[field], 1.0)).sum() * cell_area_ha)
    applied_kg_cells = applied * cell_area_ha
    off_target = float(applied_kg_cells[~field].sum() + applied_kg_cells[field & (rx0 <= 0)].sum()
                       + off_grid_kg)
    return MapMetrics(
        prescribed_kg=prescribed_kg,
        applied_kg=float(applied_total_kg),
        mass_balance_pct=_pct(applied_total_kg - prescribed_kg, prescribed_kg),
        mae_kg_ha=e.mae,
        rmse_kg_ha=e.rmse,
        bias_kg_ha=e.bias,
        mae_pct=_pct(e.mae, e.mean_target),
        rmse_pct=_pct(e.rmse, e.mean_target),
        bias_pct=_pct(e.bias, e.mean_target),
        within_5pct_area_pct=e.within_5pct_pct,
        within_10pct_area_pct=e.within_10pct_pct,
        off_target_kg=off_target,
        coverage_pct=_pct(np.count_nonzero(covered), np.count_nonzero(field)),
        covered_cells=int(np.count_nonzero(covered)),
    )


@dataclass(frozen=True)
class OverlapMetrics:
    overlap_area_pct: float
    skip_area_pct: float
    overlap_kg: float


def overlap_metrics(coverage_fraction, overlap_fraction, overlap_kg, worked_fraction,
                    in_field) -> OverlapMetrics:
    """Overlap and skips over the field's cells.

    Parameters
    ----------
    coverage_fraction, overlap_fraction : ndarray, shape (rows, cols)
        Share of each cell's area that product landed on, and that more than one pass put product
        on (`maps.AsApplied`, strips added with their passes).
    overlap_kg : ndarray, shape (rows, cols)
        Product beyond the first pass in each cell, kg.
    worked_fraction : ndarray, shape (rows, cols)
        Share of each cell the working width swept along the working stretches (the plan's worked
        area, `services.sim.section_landing.worked_fraction`).
    in_field : ndarray of bool, shape (rows, cols)
        Cells whose centre lies inside the field.

    ``overlap_area_pct`` is over the covered area, ``skip_area_pct`` over the worked area: the
    worked share of a cell that product did not cover.
    """
    field = np.asarray(in_field, bool)
    covered = np.asarray(coverage_fraction, float)[field]
    worked = np.minimum(np.asarray(worked_fraction, float)[field], 1.0)
    skipped = np.maximum(worked - covered, 0.0)
    return OverlapMetrics(
        overlap_area_pct=_pct(np.asarray(overlap_fraction, float)[field].sum(), covered.sum()),
        skip_area_pct=_pct(skipped.sum(), worked.sum()),
        overlap_kg=float(np.asarray(overlap_kg, float)[field].sum()),
    )


@dataclass(frozen=True)
class LimitMetrics:
    limited_time_pct: float
    limited_area_pct: float


def limit_metrics(limited, applying, limited_coverage, coverage_fraction, in_field) -> LimitMetrics:
    """Where the machine could not apply the map: its shaft's speed range clipped the target.

    Parameters
    ----------
    limited, applying : ndarray of bool, shape (n,)
        Ticks whose target shaft speed was clipped to the shaft's range, and ticks with a gate open.
    limited_coverage, coverage_fraction : ndarray, shape (rows, cols)
        Share of each cell's area that product metered in limited ticks landed on, and that any
        product landed on.
    in_field : ndarray of bool, shape (rows, cols)
    """
    on = np.asarray(applying, bool)
    field = np.asarray(in_field, bool)
    return LimitMetrics(
        limited_time_pct=_pct(np.count_nonzero(np.asarray(limited, bool) & on), np.count_nonzero(on)),
        limited_area_pct=_pct(np.minimum(np.asarray(limited_coverage, float)[field], 1.0).sum(),
                              np.asarray(coverage_fraction, float)[field].sum()),
    )


def rate_steps(prescribed_kg_ha, active) -> np.ndarray:
    """Tick indices where the prescription under the landing point steps to a new rate.

    A step is a change between consecutive active ticks of more than `STEP_MIN_RELATIVE` of the
    larger rate and more than `STEP_MIN_KG_HA`.
    """
    rx = np.asarray(prescribed_kg_ha, dtype=float)
    on = np.asarray(active, dtype=bool)
    prev, cur = rx[:-1], rx[1:]
    change = np.abs(cur - prev)
    big = np.fmax(np.abs(prev), np.abs(cur))
    is_step = (on[:-1] & on[1:] & np.isfinite(change)
               & (change > STEP_MIN_KG_HA) & (change > STEP_MIN_RELATIVE * big))
    return np.flatnonzero(is_step) + 1


def transitions(time_s, distance_m, prescribed_kg_ha, applied_kg_ha, active, steps=None) -> TransitionMetrics:
    """Time and distance from each rate step until the applied rate is within 10 % of the new rate.

    Parameters
    ----------
    time_s, distance_m : ndarray, shape (n,)
        Time of each tick and distance travelled by the landing point up to it (monotone).
    prescribed_kg_ha, applied_kg_ha : ndarray, shape (n,)
        Prescription under the landing point and the applied rate there, per tick (NaN where the
        rate is undefined, e.g. standing still).
    active : ndarray of bool, shape (n,)
        Ticks where the implement is on.
    steps : ndarray of int, optional
        ``rate_steps(prescribed_kg_ha, active)`` when already known (many applied rates over one
        prescription).

    A step whose rate changes again before the applied rate settles is not counted (its transition
    is unfinished, not fast or slow); one where the applied rate is already within tolerance at
    the step counts as zero.
    """
    t = np.asarray(time_s, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    rx = np.asarray(prescribed_kg_ha, dtype=float)
    applied = np.asarray(applied_kg_ha, dtype=float)
    steps = rate_steps(rx, active) if steps is None else steps
    ok = np.abs(applied - rx) <= TRANSITION_TOLERANCE * np.abs(rx)
    ok_idx = np.flatnonzero(ok)
    ends = np.append(steps[1:], len(rx))  # a step's window closes at the next step
    first_ok = ok_idx[np.minimum(np.searchsorted(ok_idx, steps), max(len(ok_idx) - 1, 0))] \
        if ok_idx.size else np.full(len(steps), len(rx))
    settled = (first_ok >= steps) & (first_ok < ends) if ok_idx.size else np.zeros(len(steps), bool)
    k, j = steps[settled], first_ok[settled]
    times, dists = t[j] - t[k], d[j] - d[k]
    if times.size == 0:
        nan = float("nan")
        return TransitionMetrics(0, nan, nan, nan, nan)
    return TransitionMetrics(
        transitions=int(times.size),
        transition_time_s_mean=float(times.mean()),
        transition_time_s_p95=float(np.percentile(times, 95)),
        transition_distance_m_mean=float(dists.mean()),
        transition_distance_m_p95=float(np.percentile(dists, 95)),
    )


# ------------------------------------------------------------------------------ per point (a log)
LOG_UNIT = "(log unit)"  # a figure in the unit of the log's rates (`vrsim evaluate`)

# The figures of `vrsim evaluate` over the points of an as-applied log, in the order it prints them.
# The run's figures above are over map cells (area-weighted, covered cells only); these are over
# logged points, each of the same weight, so mass balance and the within-shares differ in definition
# from the run's. The transitions are the run's own (`transitions`), over the points.
POINT_METRICS = (
    Metric("points", "", "Points compared",
           "records with the implement on (and a section on, where the log has section states) and both "
           "rates (with a prescription or a field: a position on the map, inside the field)"),
    Metric("applied_mean", LOG_UNIT, "Applied rate, mean", "mean applied rate over the points compared"),
    Metric("target_mean", LOG_UNIT, "Target rate, mean",
           "mean target over the points compared: the logged target, or the prescription at the point"),
    Metric("mae", LOG_UNIT, "Mean absolute error", "mean |applied - target|"),
    Metric("rmse", LOG_UNIT, "RMSE", "root mean square of applied - target"),
    Metric("bias", LOG_UNIT, "Bias", "mean applied - target"),
    Metric("mass_balance_pct", "%", "Mass balance",
           "100 (sum of applied - sum of target) / sum of target over the points, each point of the same "
           "weight (a log at a fixed rate weighs each second alike, not each hectare)"),
    Metric("within_5pct_pct", "%", "Points within +-5 %",
           "share of the points with a positive target where |applied - target| <= 5 % of it"),
    Metric("within_10pct_pct", "%", "Points within +-10 %",
           "share of the points with a positive target where |applied - target| <= 10 % of it"),
    Metric("transitions", "", "Rate steps settled",
           "steps of the target between consecutive points compared (more than 10 % and 5 kg/ha, or 5 L/ha "
           "for a volume rate) after which the applied rate came within 10 % before the next step"),
    Metric("transition_time_s_mean", "s", "Transition time, mean",
           "from a step until the applied rate is within 10 % of the new target (to the log's interval)"),
    Metric("transition_distance_m_mean", "m", "Transition distance, mean",
           "distance along the logged positions over the transition"),
)


@dataclass(frozen=True)
class PointMetrics:
    points: int
    applied_mean: float
    target_mean: float
    mae: float
    rmse: float
    bias: float
    mass_balance_pct: float
    within_5pct_pct: float
    within_10pct_pct: float
    transitions: int
    transition_time_s_mean: float
    transition_distance_m_mean: float


def point_metrics(applied, target, time_s, distance_m, compared, step_scale: float = 1.0) -> PointMetrics:
    """Applied-versus-target figures over the points of a log (`POINT_METRICS` says what each is).

    Parameters
    ----------
    applied, target : ndarray, shape (n,)
        Applied rate and what it is compared with, per point, in one unit.
    time_s, distance_m : ndarray, shape (n,)
        Time of each point and distance travelled up to it (monotone), for the transitions.
    compared : ndarray of bool, shape (n,)
        The points to compare (implement on, both rates finite, ...).
    step_scale : float
        Factor from the rates' unit to kg/ha (or L/ha), so a rate step means the same in any unit.
    """
    a = np.asarray(applied, dtype=float)
    t = np.asarray(target, dtype=float)
    use = np.asarray(compared, dtype=bool) & np.isfinite(a) & np.isfinite(t)
    e = errors(a[use], t[use])
    tm = transitions(time_s, distance_m, t * step_scale, a * step_scale, use)
    return PointMetrics(
        points=int(np.count_nonzero(use)),
        applied_mean=float(a[use].mean()) if use.any() else float("nan"),
        target_mean=e.mean_target,
        mae=e.mae,
        rmse=e.rmse,
        bias=e.bias,
        mass_balance_pct=_pct(a[use].sum() - t[use].sum(), t[use].sum()),
        within_5pct_pct=e.within_5pct_pct,
        within_10pct_pct=e.within_10pct_pct,
        transitions=tm.transitions,
        transition_time_s_mean=tm.transition_time_s_mean,
        transition_distance_m_mean=tm.transition_distance_m_mean,
    )
