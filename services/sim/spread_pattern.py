"""Spread-pattern figures as EN 13739 / ISO 5690 define them, and a simulated catch-tray test.

A spreader's transverse pattern (relative mass per lateral offset from one pass) is overlapped with
its neighbours' at a driving width: *to-and-fro* (every other pass driven the other way, so its
pattern mirrored: how the standards overlap by default) or *racetrack* (every pass the same way).
The coefficient of variation of the overlapped rate across one driving width (sample standard
deviation over the mean, %) judges the machine at that width; the *effective working width* is the
largest driving width whose CV stays within a limit (15 %, the usual one).

`overlapped`, `cv_pct` and `effective_width_m` are pure numpy on a sampled profile; `catch_tray_test`
puts a spinner's real footprint (`maps.SpinnerThrow`) through the deposition engine over adjacent
passes and reads a row of catch trays, as a test institute lays them out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim.common import VrsimError
from vrsim.vehicle.spinner import SpinnerSpec, TransversePattern

__all__ = ["CV_LIMIT_PCT", "OVERLAP_MODES", "TrayTest", "catch_tray_test", "cv_pct", "effective_width_m",
           "overlapped"]

CV_LIMIT_PCT = 15.0
OVERLAP_MODES = ("to_and_fro", "racetrack")
ACROSS_POINTS = 400  # points across one driving width at which the overlapped rate is read
WIDTH_SCAN_STEP_M = 0.1  # driving widths scanned for the effective width, then bisected
WIDTH_TOLERANCE_M = 0.005
TRAY_ROW_MARGIN_M = 5.0  # ground each pass runs beyond the tray row's throw-shifted product
NOMINAL_RATE_KG_HA = 100.0  # the rate the simulated passes apply (the figures are relative)
UTM = "EPSG:32632"  # any metric CRS: the trays' ground is synthetic
ORIGIN = (500_000.0, 5_300_000.0)


def overlapped(offset_m, mass, driving_width_m: float, mode: str = "to_and_fro",
               points: int = ACROSS_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The rate that passes `driving_width_m` apart lay down across one driving width.

    Parameters
    ----------
    offset_m, mass : array_like, shape (n,)
        One pass's transverse profile: lateral offsets (m, increasing, positive to the left of
        travel) and relative mass there (linear between them, zero beyond).
    driving_width_m : float
        Distance between neighbouring passes' centre lines, m (> 0).
    mode : str
        ``"to_and_fro"`` (every other pass mirrored) or ``"racetrack"``.
    points : int
        Points across the driving width.

    Returns
    -------
    position_m, rate : ndarray, shape (points,)
        Positions across one driving width centred on a pass's centre line (m, evenly spaced
        centres, in (-w/2, w/2)) and the overlapped relative mass there (the profile's units). The
        window holds half of the gap to each neighbour: to and fro, an uneven pattern's rate repeats
        over two driving widths (the gaps on either side of a pass differ), and half of each gap is
        one of each, so the figures do not depend on which way the first pass is driven. It is
        where catch trays lie across a middle pass.
    """
    offset, mass, width = _checked_profile(offset_m, mass, driving_width_m, mode)
    position = ((np.arange(points) + 0.5) / points - 0.5) * width
    reach = max(abs(offset[0]), abs(offset[-1]))
    k = np.arange(-math.ceil(reach / width) - 1, math.ceil(reach / width) + 2)
    lateral = position[None, :] - k[:, None] * width  # each pass's offset of every position
    mirrored = (mode == "to_and_fro") & (k % 2 == 1)
    lateral = np.where(mirrored[:, None], -lateral, lateral)
    return position, np.interp(lateral, offset, mass, left=0.0, right=0.0).sum(axis=0)


def cv_pct(offset_m, mass, driving_width_m: float, mode: str = "to_and_fro") -> float:
    """Coefficient of variation (%) of the overlapped rate across one driving width (`overlapped`):
    sample standard deviation over the mean, as EN 13739 computes it from its trays."""
    _, rate = overlapped(offset_m, mass, driving_width_m, mode)
    return _sample_cv_pct(rate)


def _sample_cv_pct(values) -> float:
    """Sample standard deviation (n - 1) over the mean of `values`, %; infinite where nothing lies."""
    values = np.asarray(values, dtype=float)
    mean = float(np.mean(values))
    return float(np.std(values, ddof=1) / mean * 100.0) if mean > 0 else math.inf


def effective_width_m(offset_m, mass, limit_pct: float = CV_LIMIT_PCT, mode: str = "to_and_fro") -> float:
    """The largest driving width (m) whose CV (`cv_pct`) is at most `limit_pct`; 0.0 if none is.

    Widths are scanned every `WIDTH_SCAN_STEP_M` up to the profile's full extent (beyond it passes
    leave gaps), and the last one within the limit is refined by bisection to `WIDTH_TOLERANCE_M`.
    """
    offset, mass, _ = _checked_profile(offset_m, mass, 1.0, mode)
    extent = float(offset[-1] - offset[0])
    widths = np.arange(WIDTH_SCAN_STEP_M, extent + WIDTH_SCAN_STEP_M, WIDTH_SCAN_STEP_M)
    within = np.array([cv_pct(offset, mass, w, mode) <= limit_pct for w in widths])
    if not within.any():
        return 0.0
    last = int(np.flatnonzero(within)[-1])
    if last == widths.size - 1:
        return float(widths[last])
    lo, hi = float(widths[last]), float(widths[last + 1])
    while hi - lo > WIDTH_TOLERANCE_M:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if cv_pct(offset, mass, mid, mode) <= limit_pct else (lo, mid)
    return lo


def _checked_profile(offset_m, mass, driving_width_m: float, mode: str):
    offset, mass = np.asarray(offset_m, dtype=float).ravel(), np.asarray(mass, dtype=float).ravel()
    if offset.size < 2 or offset.size != mass.size or not np.all(np.diff(offset) > 0):
        raise VrsimError("spread pattern: a profile needs >= 2 increasing offsets, one mass each")
    if not (np.all(np.isfinite(mass)) and np.all(mass >= 0) and mass.any()):
        raise VrsimError("spread pattern: the profile's masses must be finite, >= 0 and not all zero")
    if not (math.isfinite(driving_width_m) and driving_width_m > 0):
        raise VrsimError(f"spread pattern: driving width {driving_width_m!r} m must be > 0")
    if mode not in OVERLAP_MODES:
        raise VrsimError(f"spread pattern: mode {mode!r} is not one of {', '.join(OVERLAP_MODES)}")
    return offset, mass, float(driving_width_m)


@dataclass(frozen=True)
class TrayTest:
    """A simulated catch-tray test of a spinner (`catch_tray_test`).

    Attributes
    ----------
    driving_width_m, tray_width_m : float
        Distance between the passes, m; width of each tray across the passes, m.
    passes : int
        Adjacent passes driven to and fro (the middle one northwards).
    offset_m : ndarray, shape (trays,)
        Each tray's centre across the row, m from the middle pass's centre line (positive: its left).
    pass_rate_pct : ndarray, shape (passes, trays)
        What each pass put in each tray, % of the nominal rate the passes apply at the driving width.
    total_pct : ndarray, shape (trays,)
        All passes together, % of the nominal rate.
    in_width : ndarray of bool, shape (trays,)
        The trays within the middle pass's driving width, over which the CV is taken.
    cv_pct : float
        CV of the trays within the driving width (three or more passes to and fro), %.
    cv_racetrack_pct : float
        CV of the middle pass's profile overlapped racetrack-fashion at the driving width, %.
    effective_width_m : float
        Largest driving width whose CV (to and fro, from the middle pass's profile) is within 15 %, m.
    """

    driving_width_m: float
    tray_width_m: float
    passes: int
    offset_m: np.ndarray
    pass_rate_pct: np.ndarray
    total_pct: np.ndarray
    in_width: np.ndarray
    cv_pct: float
    cv_racetrack_pct: float
    effective_width_m: float


def catch_tray_test(spec: SpinnerSpec, pattern: TransversePattern, driving_width_m: float,
                    tray_width_m: float = 0.5) -> TrayTest:
    """Drive a spinner over a row of catch trays: adjacent straight passes `driving_width_m` apart,
    to and fro, each disc's product per tick put down through the real footprint (`maps.SpinnerThrow`)
    by the deposition engine on a grid of `tray_width_m` cells, and the row across the passes read.

    Three passes (more where the pattern reaches beyond the neighbours' centre lines), so the middle
    pass's driving width gets all the product the standards' overlap gives it.

    Parameters
    ----------
    spec : SpinnerSpec
        The spinner (its spread width and throw distance).
    pattern : TransversePattern
        Its transverse pattern (`SpinnerSpec.transverse_pattern`).
    driving_width_m, tray_width_m : float
        Distance between the passes and each tray's width across them, m (0 < tray <= driving).
    """
    from vrsim.maps import ColumnDeposit, SpinnerThrow, synthetic

    w, tray = float(driving_width_m), float(tray_width_m)
    if not (math.isfinite(tray) and 0 < tray <= w):
        raise VrsimError(f"catch trays: tray width {tray!r} m must be > 0 and at most the driving width "
                         f"{w:g} m")
    half = spec.half_width_m
    passes = 2 * max(1, math.ceil((half - w / 2) / w)) + 1
    middle = passes // 2
    cols = 2 * math.ceil((middle * w + half + 2 * tray) / tray)
    travel = 2 * (spec.throw_distance_m + TRAY_ROW_MARGIN_M)
    rows = 2 * math.ceil((travel / 2 + spec.throw_distance_m + 2 * tray) / tray) + 1  # odd: a middle row
    x_c, y_c = ORIGIN[0] + cols / 2 * tray, ORIGIN[1] + rows / 2 * tray
    grid = synthetic.uniform((ORIGIN[0], ORIGIN[1], ORIGIN[0] + cols * tray, ORIGIN[1] + rows * tray), UTM,
                             cell_size_m=tray, rate_kg_ha=NOMINAL_RATE_KG_HA)
    # Ticks of about a metre along each pass, two items (left, right disc) per tick.
    ticks = math.ceil(travel)
    along = np.linspace(-travel / 2, travel / 2, ticks + 1)
    j = np.repeat(np.arange(passes), ticks * 2)
    north = (j - middle) % 2 == 0
    t = np.tile(np.repeat(np.arange(ticks), 2), passes)
    side = np.tile([1.0, -1.0], passes * ticks)
    heading = np.where(north, 1.0, -1.0)
    x = x_c + (j - middle) * w
    y0, y1 = y_c + heading * along[t], y_c + heading * along[t + 1]
    footprint = SpinnerThrow(x, y0, x, y1, side, half, pattern.offset_m, pattern.mass_per_m,
                             spec.throw_distance_m)
    kg = NOMINAL_RATE_KG_HA * w / 10_000.0 * travel / ticks / 2  # each disc's half of a tick
    columns = np.where(j[:, None] == np.arange(passes)[None, :], kg, 0.0)
    applied = ColumnDeposit(grid, footprint).apply(columns).applied_kg_ha
    centres_x, centres_y = grid.cell_centres()
    row = int(np.argmin(np.abs(np.asarray(centres_y) - y_c)))
    offset = x_c - np.asarray(centres_x)  # the middle pass drives north: its left is west
    order = np.argsort(offset)
    pass_pct = applied[:, row, order] / NOMINAL_RATE_KG_HA * 100.0
    offset = offset[order]
    total = pass_pct.sum(axis=0)
    in_width = np.abs(offset) <= w / 2
    profile = pass_pct[middle]
    return TrayTest(w, tray, passes, offset, pass_pct, total, in_width,
                    _sample_cv_pct(total[in_width]),
                    cv_pct(offset, profile, w, "racetrack"), effective_width_m(offset, profile))
