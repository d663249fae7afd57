"""Rate steps and transitions: how long the applied rate takes to follow a step of the prescription.

A *rate step* is a change of the prescription under the landing point between consecutive working
ticks of more than `STEP_MIN_RELATIVE` of the larger rate and more than `STEP_MIN_KG_HA`. Its
*transition* ends where the applied rate settles: it enters and stays within `TRANSITION_TOLERANCE` of
the new rate for `SETTLE_HOLD_S`, or until the step's window (to the next step, or to where the
implement goes off) closes. Steps into zero rate (sections closing) and steps whose window closes
before the rate settles are counted apart and left out of the mean and the percentiles, so that both
describe the same steps. Pure functions over numpy arrays; `services.sim.metrics` reports them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TRANSITION_TOLERANCE = 0.10  # "within 10 % of the new rate"
SETTLE_HOLD_S = 1.0  # ... and staying there this long (or to the step's window end) is settling
STEP_MIN_RELATIVE = 0.10  # a rate change of more than 10 % ...
STEP_MIN_KG_HA = 5.0  # ... and more than 5 kg/ha is a rate step


@dataclass(frozen=True)
class TransitionMetrics:
    transitions: int
    transition_time_s_mean: float
    transition_time_s_p95: float
    transition_distance_m_mean: float
    transition_distance_m_p95: float
    transitions_to_zero: int
    transitions_cut: int


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
    """Time and distance from each rate step until the applied rate settles on the new rate: the
    figures of `transition_spans` (its parameters)."""
    return transition_figures(*transition_spans(time_s, distance_m, prescribed_kg_ha, applied_kg_ha, active,
                                                steps))


def transition_spans(time_s, distance_m, prescribed_kg_ha, applied_kg_ha, active, steps=None):
    """Time and distance from each rate step until the applied rate settles on the new rate.

    Parameters
    ----------
    time_s, distance_m : ndarray, shape (n,)
        Time of each tick and distance travelled by the landing point up to it (monotone).
    prescribed_kg_ha, applied_kg_ha : ndarray, shape (n,)
        Prescription under the landing point and the applied rate there, per tick (NaN where the
        rate is undefined, e.g. standing still or every section off: not within tolerance).
    active : ndarray of bool, shape (n,)
        Ticks where the implement is on.
    steps : ndarray of int, optional
        ``rate_steps(prescribed_kg_ha, active)`` when already known (many applied rates over one
        prescription).

    A step's window runs from the step to the next step or to the first tick with the implement off,
    whichever comes first. The transition ends at the first tick of the window from which the applied
    rate stays within `TRANSITION_TOLERANCE` of the new rate for `SETTLE_HOLD_S` or to the window's
    end (zero when it does so from the step on; an overshoot that leaves the band and comes back ends
    where it comes back; a rate that leaves the band later, at the end of the pass say, is a new
    disturbance, not this step's). A step into zero rate is counted in ``transitions_to_zero``; one
    whose window ends outside the band in ``transitions_cut`` (unfinished, not fast or slow); neither
    is in the mean or the percentiles.

    Returns
    -------
    times_s, distances_m : ndarray
        Time and distance of each settled step's transition.
    to_zero, cut : int
        Steps into zero rate, and steps cut.
    """
    t = np.asarray(time_s, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    rx = np.asarray(prescribed_kg_ha, dtype=float)
    applied = np.asarray(applied_kg_ha, dtype=float)
    on = np.asarray(active, dtype=bool)
    n = len(rx)
    steps = rate_steps(rx, on) if steps is None else np.asarray(steps, dtype=int)
    ticks = np.arange(n)
    # For each tick: the first tick at or after it with the implement off (n: none), the last tick at
    # or before it outside the band (-1: none) and the first at or after it outside the band (n: none).
    next_off = np.minimum.accumulate(np.where(on, n, ticks)[::-1])[::-1]
    ok = np.abs(applied - rx) <= TRANSITION_TOLERANCE * np.abs(rx)
    last_out = np.maximum.accumulate(np.where(ok, -1, ticks))
    next_out = np.minimum.accumulate(np.where(ok, n, ticks)[::-1])[::-1]
    # A tick from which the rate stays in the band for the hold (1 ns: the ticks' float times).
    held = ok & ((t[np.minimum(next_out, n - 1)] - t >= SETTLE_HOLD_S - 1e-9) | (next_out == n))
    next_held = np.minimum.accumulate(np.where(held, ticks, n)[::-1])[::-1]
    to_zero = rx[steps] <= 0
    ends = np.minimum(np.append(steps[1:], n), next_off[steps])  # each step's window: [step, end)
    # Settled at the first held tick of the window, or where the band holds to the window's end.
    tail = np.maximum(last_out[ends - 1] + 1, steps)
    settle = np.minimum(next_held[steps], np.where(tail < ends, tail, n))
    settled = ~to_zero & (settle < ends)
    k, j = steps[settled], settle[settled]
    cut = int(np.count_nonzero(~to_zero & ~settled))
    return t[j] - t[k], d[j] - d[k], int(np.count_nonzero(to_zero)), cut


def transition_figures(times, dists, to_zero: int, cut: int) -> TransitionMetrics:
    """`TransitionMetrics` of the settled steps' transition times (s) and distances (m) and the counts
    of steps into zero rate and cut (`transition_spans`; a run accounted in parts joins its parts'
    spans first)."""
    counts = dict(transitions=int(times.size), transitions_to_zero=to_zero, transitions_cut=cut)
    if times.size == 0:
        nan = float("nan")
        return TransitionMetrics(transition_time_s_mean=nan, transition_time_s_p95=nan,
                                 transition_distance_m_mean=nan, transition_distance_m_p95=nan, **counts)
    return TransitionMetrics(
        transition_time_s_mean=float(times.mean()),
        transition_time_s_p95=float(np.percentile(times, 95)),
        transition_distance_m_mean=float(dists.mean()),
        transition_distance_m_p95=float(np.percentile(dists, 95)),
        **counts,
    )


# ------------------------------------------------------------------------------ per point (a log)
