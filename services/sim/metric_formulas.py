"""The formulas of a run's and a log's figures: pure functions over numpy arrays, no I/O.

What each figure means, and the table of every figure a run reports (`METRICS`, `POINT_METRICS`), is
`services.sim.metrics`, which re-exports these names: its table reads a run's accounts
(`services.sim.accounting.Accounts`), which these formulas fill in.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from vrsim.services.sim.transitions import transitions

COVERED_FRACTION = 0.9  # swept share of a cell's area above which it counts as covered


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


def _pct(part: float, whole: float) -> float:
    return float(100.0 * part / whole) if whole > 0 else float("nan")


@dataclass(frozen=True)
class _Errors:
    """Applied against target over paired values (map cells or logged points)."""

    mean_target: float
    mae: float
    rmse: float
    bias: float
    within_5pct_pct: float
    within_10pct_pct: float


def _errors(applied, target, weight=None) -> _Errors:
    """``e = applied - target``: mean |e|, sqrt(mean e^2), mean e, and the share of the values with a
    positive target where |e| <= 5 % (10 %) of it; NaN for no values.

    Parameters
    ----------
    applied, target : ndarray, shape (n,)
        Paired values, finite.
    weight : ndarray, shape (n,), optional
        What each value weighs in the within-shares (an area); default: each alike. The means are
        each alike whatever the weight.
    """
    err = applied - target
    nan = float("nan")
    positive = target > 0
    rel = np.abs(err[positive]) / target[positive]
    w = np.ones(rel.size) if weight is None else np.asarray(weight, float)[positive]
    return _Errors(
        mean_target=float(target.mean()) if err.size else nan,
        mae=float(np.abs(err).mean()) if err.size else nan,
        rmse=float(np.sqrt((err**2).mean())) if err.size else nan,
        bias=float(err.mean()) if err.size else nan,
        within_5pct_pct=_pct(w[rel <= 0.05].sum(), w.sum()),
        within_10pct_pct=_pct(w[rel <= 0.10].sum(), w.sum()),
    )


def map_metrics(prescribed_kg_ha, applied_kg_ha, coverage_fraction, in_field, cell_area_ha,
                applied_total_kg, off_grid_kg=0.0, *, worked_fraction) -> MapMetrics:
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
    worked_fraction : ndarray, shape (rows, cols)
        Share of each cell the plan's working width swept (`services.sim.section_landing.worked_fraction`):
        the ground the within-shares judge (`within_band`).
    """
    rx = np.asarray(prescribed_kg_ha, dtype=float)
    applied = np.asarray(applied_kg_ha, dtype=float)
    cover = np.asarray(coverage_fraction, dtype=float)
    field = np.asarray(in_field, dtype=bool)
    if not (rx.shape == applied.shape == cover.shape == field.shape):
        raise ValueError("prescribed, applied, coverage and in_field must have the same shape")
    rx0 = np.nan_to_num(rx, nan=0.0)
    covered = field & (cover >= COVERED_FRACTION) & np.isfinite(rx)
    e = _errors(applied[covered], rx[covered])
    band = within_band(rx0, applied, worked_fraction, field)
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
        within_5pct_area_pct=band.within_5pct_pct,
        within_10pct_area_pct=band.within_10pct_pct,
        off_target_kg=off_target,
        coverage_pct=_pct(np.count_nonzero(covered), np.count_nonzero(field)),
        covered_cells=int(np.count_nonzero(covered)),
    )


def within_band(prescribed_kg_ha, applied_kg_ha, worked_fraction, in_field) -> _Errors:
    """The within-shares over the worked ground that asks for product: every cell inside the field
    with a prescription above 0 that the working width swept, weighted by its worked share, its rate
    the product per worked area (``applied / worked``). Bare and partly covered cells count, outside
    the band unless their rate is in it: closing sections early or switching late lowers the share,
    as it leaves the ground short; a cell the working width swept only in part (the field's edge,
    a pass's end) is judged on the part swept.

    Parameters
    ----------
    prescribed_kg_ha, applied_kg_ha, worked_fraction : ndarray, shape (rows, cols)
        Prescription (0 or NaN: asks for nothing), applied product per cell area, swept share of each
        cell (above 1 where passes meet: counted as 1, so a cell twice covered applies twice).
    in_field : ndarray of bool, shape (rows, cols)
    """
    rx = np.asarray(prescribed_kg_ha, float)
    worked = np.minimum(np.asarray(worked_fraction, float), 1.0)
    with np.errstate(invalid="ignore"):
        asks = np.asarray(in_field, bool) & (rx > 0) & (worked > 0)
    return _errors(np.asarray(applied_kg_ha, float)[asks] / worked[asks], rx[asks], worked[asks])


@dataclass(frozen=True)
class OverlapMetrics:
    overlap_area_pct: float
    skip_area_pct: float
    off_as_prescribed_area_pct: float
    overlap_kg: float


def overlap_metrics(coverage_fraction, overlap_fraction, overlap_kg, worked_fraction, in_field,
                    prescribed_kg_ha) -> OverlapMetrics:
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
    prescribed_kg_ha : ndarray, shape (rows, cols)
        The prescription (NaN on nodata).

    ``overlap_area_pct`` is over the covered area. The worked share of a cell that product did not
    cover is bare: ``skip_area_pct`` is the bare area of cells whose prescription is above 0 over
    their worked area, ``off_as_prescribed_area_pct`` the bare area of the other cells (zero rate or
    nodata: the sections rightly closed there) over the whole worked area.
    """
    field = np.asarray(in_field, bool)
    covered = np.asarray(coverage_fraction, float)[field]
    worked = np.minimum(np.asarray(worked_fraction, float)[field], 1.0)
    bare = np.maximum(worked - covered, 0.0)
    asks = np.asarray(prescribed_kg_ha, float)[field] > 0  # NaN (nodata): asks for nothing
    return OverlapMetrics(
        overlap_area_pct=_pct(np.asarray(overlap_fraction, float)[field].sum(), covered.sum()),
        skip_area_pct=_pct(bare[asks].sum(), worked[asks].sum()),
        off_as_prescribed_area_pct=_pct(bare[~asks].sum(), worked.sum()),
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
        Ticks in which a drive's target shaft speed was clipped to the shaft's range, and ticks with a
        gate open.
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


# Below this ground speed (1.8 km/h) a record is the machine standing or creeping: its flow over almost
# no ground logs hundreds of gal/ac that no hectare got (a sprayer holds a minimum flow at a stop).
STANDSTILL_M_S = 0.5
# An applied rate above this many times its target is a start-up (a preset flow before the demand
# catches up) or a logging fault, not the controller's error: counted, and kept out of the means.
OUTLIER_MULTIPLE = 5.0


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
    weighting: str
    timestamps: int
    within_5pct_timestamps_pct: float
    within_10pct_timestamps_pct: float
    transitions: int
    transition_time_s_mean: float
    transition_distance_m_mean: float
    transition_peak_error_pct_mean: float
    to_zero_events: int
    to_zero_time_s_mean: float
    pass_start_events: int
    pass_start_time_s_mean: float
    pass_start_peak_error_pct_mean: float
    pass_end_events: int
    pass_end_time_s_mean: float
    pass_end_peak_error_pct_mean: float
    standstill_records: int
    standstill_speed_m_s: float
    speed_from: str
    outlier_records: int
    outlier_multiple: float
    outliers_included: bool
    sessions: int


@dataclass(frozen=True)
class LogScreen:
    """What a log's records were screened for before its figures: the `POINT_METRICS` rows of the same
    names (the default: nothing screened, one session)."""

    standstill_records: int = 0
    standstill_speed_m_s: float = STANDSTILL_M_S
    speed_from: str = "not known"
    outlier_records: int = 0
    outlier_multiple: float = OUTLIER_MULTIPLE
    outliers_included: bool = False
    sessions: int = 1


def outliers(applied, target, multiple: float = OUTLIER_MULTIPLE) -> np.ndarray:
    """The records applying more than `multiple` times a target above 0 (bool, shape (n,))."""
    a, t = np.asarray(applied, float), np.asarray(target, float)
    with np.errstate(invalid="ignore"):
        return (t > 0) & (a > multiple * t)


def point_metrics(applied, target, time_s, distance_m, compared, step_scale: float = 1.0, area_m2=None,
                  screen: LogScreen | None = None) -> PointMetrics:
    """Applied-versus-target figures over the points of a log (`POINT_METRICS` says what each is).

    Parameters
    ----------
    applied, target : ndarray, shape (n,)
        Applied rate and what it is compared with, per point, in one unit.
    time_s, distance_m : ndarray, shape (n,)
        Time of each point and distance travelled up to it (monotone), for the transitions; points
        of one time are one timestamp.
    compared : ndarray of bool, shape (n,)
        The points to compare (implement on, both rates finite, not at a standstill, ...).
    step_scale : float
        Factor from the rates' unit to kg/ha (or L/ha), so a rate step means the same in any unit.
    area_m2 : ndarray, shape (n,), optional
        Each point's area (distance since the previous record x width): mass balance and the
        within-shares are weighted by it when every point compared has one (finite, >= 0, not all 0).
    screen : LogScreen, optional
        What was screened out before `compared`, reported as it is.
    """
    a = np.asarray(applied, dtype=float)
    t = np.asarray(target, dtype=float)
    use = np.asarray(compared, dtype=bool) & np.isfinite(a) & np.isfinite(t)
    weight = _area_weight(area_m2, use)
    w = np.ones(a.size) if weight is None else weight
    e = _errors(a[use], t[use], w[use])
    stamps = _per_timestamp(a[use], t[use], np.asarray(time_s, float)[use], w[use], weight is not None)
    tm = transitions(time_s, distance_m, t * step_scale, a * step_scale, use)
    weighted_target = (t * w)[use].sum()
    return PointMetrics(
        points=int(np.count_nonzero(use)),
        applied_mean=float(a[use].mean()) if use.any() else float("nan"),
        target_mean=e.mean_target,
        mae=e.mae,
        rmse=e.rmse,
        bias=e.bias,
        mass_balance_pct=_pct((a * w)[use].sum() - weighted_target, weighted_target),
        within_5pct_pct=e.within_5pct_pct,
        within_10pct_pct=e.within_10pct_pct,
        weighting="record" if weight is None else "area",
        timestamps=stamps[0],
        within_5pct_timestamps_pct=stamps[1].within_5pct_pct,
        within_10pct_timestamps_pct=stamps[1].within_10pct_pct,
        transitions=tm.transitions,
        transition_time_s_mean=tm.transition_time_s_mean,
        transition_distance_m_mean=tm.transition_distance_m_mean,
        transition_peak_error_pct_mean=tm.rate_step.peak_error_pct_mean,
        **_event_figures(tm),
        **asdict(screen or LogScreen()),
    )


def _event_figures(tm) -> dict:
    """The `PointMetrics` fields of the event classes beside the rate steps."""
    out = {}
    for kind in ("to_zero", "pass_start", "pass_end"):
        part = getattr(tm, kind)
        out.update({f"{kind}_events": part.events, f"{kind}_time_s_mean": part.time_s_mean})
        if kind != "to_zero":
            out[f"{kind}_peak_error_pct_mean"] = part.peak_error_pct_mean
    return out


def _area_weight(area_m2, use: np.ndarray) -> np.ndarray | None:
    """Each point's area (0 where not used) when every point used has one (finite, >= 0, not all 0),
    else None: a log that gives the area of only some points cannot weigh the rest."""
    if area_m2 is None:
        return None
    area = np.asarray(area_m2, dtype=float)
    used = area[use]
    if not (used.size and np.isfinite(used).all() and (used >= 0).all() and used.sum() > 0):
        return None
    return np.where(use, area, 0.0)


def _per_timestamp(applied, target, time_s, weight, by_area: bool) -> tuple[int, _Errors]:
    """(timestamps, their within-shares): the points grouped by time; at each, the machine's rate is
    its points' mean by `weight` (a per-section log's sections: the machine's rate over its open
    width), and the timestamp weighs its points' area (`by_area`) or 1."""
    times, group = np.unique(time_s, return_inverse=True)
    total = np.bincount(group, weights=weight, minlength=times.size)
    ok = total > 0  # a timestamp whose points have no area has no rate over ground
    mean = [np.bincount(group, weights=v * weight, minlength=times.size)[ok] / total[ok]
            for v in (applied, target)]
    return int(times.size), _errors(*mean, total[ok] if by_area else None)
