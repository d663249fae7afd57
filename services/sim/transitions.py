"""Rate steps and transitions: how long the applied rate takes to follow a change, by event class.

A *rate step* is a change of the prescription under the landing point between consecutive working
ticks of more than `STEP_MIN_RELATIVE` of the larger rate and more than `STEP_MIN_KG_HA`. The events
(`EVENTS`), each only where product was going on before it (sections open):

- ``rate_step``: a step to a rate above 0 with the sections open;
- ``to_zero``: a step to a zero rate with the sections open (they are to close);
- ``pass_start``: sections opening: the first tick with product going on in a working stretch (the
  start of a pass) or after every section was closed within it (a reopening), under a rate above 0;
- ``pass_end``: sections closing: the last tick with product going on before the implement turns off
  or every section closes, under a rate above 0.

A step's or an opening's *transition* ends where the applied rate settles: it enters and stays within
`TRANSITION_TOLERANCE` of the new rate for `SETTLE_HOLD_S`, or until the event's window (to the next
step, or to where the implement goes off) closes; one whose window closes first is *cut* (unfinished,
neither fast nor slow) and left out of the times and distances. A step to zero settles where product
stops (nothing applied, or at most `TRANSITION_TOLERANCE` of the rate before). A pass end looks back:
its transition is the last stretch before the closing over which the applied rate was outside the
band without coming back (0 when it closes in the band), from the last event on. The peak error of an
event is the largest ``(applied - rate) / rate`` (%, signed) over its transition where product was
going on (none for a step to zero: the rate before it is its peak).

Figures of a class that rest on fewer than `MIN_EVENTS` events are NaN (null), not a number: the
class's counts say why. Pure functions over numpy arrays; `services.sim.metrics` reports them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

TRANSITION_TOLERANCE = 0.10  # "within 10 % of the new rate"
SETTLE_HOLD_S = 1.0  # ... and staying there this long (or to the step's window end) is settling
STEP_MIN_RELATIVE = 0.10  # a rate change of more than 10 % ...
STEP_MIN_KG_HA = 5.0  # ... and more than 5 kg/ha is a rate step
EVENTS = ("rate_step", "to_zero", "pass_start", "pass_end")
MIN_EVENTS = 5  # a class's mean, percentile or peak rests on at least this many events


@dataclass(frozen=True)
class TransitionEvents:
    """The events of a run's ticks (or of a stretch of them), one entry each.

    Attributes
    ----------
    kind : ndarray of int
        The event's class, an index into `EVENTS`.
    settled : ndarray of bool
        Whether its transition ended within its window (a pass end's always does).
    time_s, distance_m : ndarray of float
        Its transition's time and distance along the landing path (NaN where not settled).
    peak_error_pct : ndarray of float
        Its peak error (NaN: no tick with product going on in its transition).
    """

    kind: np.ndarray
    settled: np.ndarray
    time_s: np.ndarray
    distance_m: np.ndarray
    peak_error_pct: np.ndarray

    @classmethod
    def joined(cls, parts) -> TransitionEvents:
        """The events of consecutive stretches, in order."""
        parts = list(parts)
        if not parts:
            return cls(np.zeros(0, np.int64), np.zeros(0, bool), *(np.zeros(0) for _ in range(3)))
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))


@dataclass(frozen=True)
class EventFigures:
    """The figures of one event class: ``events`` in all, ``cut`` of them unsettled; the settled ones'
    transition time (s) and distance (m), mean and 95th percentile; the mean of the events' |peak
    error| (%). NaN where fewer than `MIN_EVENTS` events stand behind a figure."""

    events: int
    cut: int
    time_s_mean: float
    time_s_p95: float
    distance_m_mean: float
    distance_m_p95: float
    peak_error_pct_mean: float

    @classmethod
    def of(cls, ev: TransitionEvents, kind: int) -> EventFigures:
        mine = ev.kind == kind
        done = mine & ev.settled
        times, dists = ev.time_s[done], ev.distance_m[done]
        peaks = np.abs(ev.peak_error_pct[mine])
        peaks = peaks[np.isfinite(peaks)]
        enough = times.size >= MIN_EVENTS
        nan = float("nan")
        return cls(
            events=int(np.count_nonzero(mine)), cut=int(np.count_nonzero(mine & ~ev.settled)),
            time_s_mean=float(times.mean()) if enough else nan,
            time_s_p95=float(np.percentile(times, 95)) if enough else nan,
            distance_m_mean=float(dists.mean()) if enough else nan,
            distance_m_p95=float(np.percentile(dists, 95)) if enough else nan,
            peak_error_pct_mean=float(peaks.mean()) if peaks.size >= MIN_EVENTS else nan,
        )


@dataclass(frozen=True)
class TransitionMetrics:
    """The figures of each event class (`EVENTS`); the rate steps' under their long-standing names."""

    rate_step: EventFigures
    to_zero: EventFigures
    pass_start: EventFigures
    pass_end: EventFigures

    @property
    def transitions(self) -> int:
        """Rate steps settled: the steps of the transition figures."""
        return self.rate_step.events - self.rate_step.cut

    transition_time_s_mean = property(lambda self: self.rate_step.time_s_mean)
    transition_distance_m_mean = property(lambda self: self.rate_step.distance_m_mean)


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
    """The figures of each event class over ticks: `transition_figures` of `transition_events` (its
    parameters)."""
    return transition_figures(transition_events(time_s, distance_m, prescribed_kg_ha, applied_kg_ha, active,
                                                steps))


def transition_figures(events: TransitionEvents) -> TransitionMetrics:
    """`TransitionMetrics` of events (a run accounted in parts joins its parts' events first)."""
    return TransitionMetrics(*(EventFigures.of(events, k) for k in range(len(EVENTS))))


def transition_events(time_s, distance_m, prescribed_kg_ha, applied_kg_ha, active, steps=None,
                      upto: int | None = None) -> TransitionEvents:
    """Every event of the ticks (module docstring) and its transition.

    Parameters
    ----------
    time_s, distance_m : ndarray, shape (n,)
        Time of each tick and distance travelled by the landing point up to it (monotone).
    prescribed_kg_ha, applied_kg_ha : ndarray, shape (n,)
        Prescription under the landing point and the applied rate there, per tick (NaN where the
        rate is undefined: standing still or every section off, no product going on).
    active : ndarray of bool, shape (n,)
        Ticks where the implement is on.
    steps : ndarray of int, optional
        ``rate_steps(prescribed_kg_ha[:upto], active[:upto])`` when already known.
    upto : int, optional
        Only events at ticks before this one (a stretch's own ticks; the ticks after it are its
        look-ahead, which the windows may reach into). Default: all.

    Returns
    -------
    TransitionEvents
        In the order rate steps and steps to zero (by tick), openings, closings.
    """
    t = np.asarray(time_s, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    rx = np.asarray(prescribed_kg_ha, dtype=float)
    applied = np.asarray(applied_kg_ha, dtype=float)
    on = np.asarray(active, dtype=bool)
    n = len(rx)
    upto = n if upto is None else upto
    if steps is None:
        steps = rate_steps(rx[:upto], on[:upto])
    steps = np.asarray(steps, dtype=int)
    ticks = np.arange(n)
    flowing = on & np.isfinite(applied)            # product going on
    before = np.append(False, flowing[:-1])        # ... at the tick before
    after = np.append(flowing[1:], False)          # ... at the tick after
    positive = rx > 0
    steps = steps[before[steps]]                   # a step with the sections closed is no transition
    # An opening is never a step: a step's tick follows one with product going on.
    openings = np.flatnonzero(flowing[:upto] & ~before[:upto] & positive[:upto])
    rising, falling = steps[positive[steps]], steps[~positive[steps]]
    closings = np.flatnonzero(flowing[:upto] & ~after[:upto] & positive[:upto])

    next_off = np.minimum.accumulate(np.where(on, n, ticks)[::-1])[::-1]
    with np.errstate(invalid="ignore"):
        ok = np.abs(applied - rx) <= TRANSITION_TOLERANCE * np.abs(rx)
        rel_pct = np.where(flowing & positive, 100.0 * (applied - rx) / rx, np.nan)
        # The rate before a step to zero: the last positive prescription of a working tick.
        last_rate = np.maximum.accumulate(np.where(on & positive, ticks, -1))
        before_rate = np.where(last_rate >= 0, rx[np.maximum(last_rate, 0)], 0.0)
        gone = ~(applied > TRANSITION_TOLERANCE * before_rate)    # NaN: nothing going on

    events = np.sort(np.concatenate([steps, openings]))   # each window closes at the next of these
    starts = np.concatenate([rising, falling, openings])
    ends = np.minimum(np.append(events, n)[np.searchsorted(events, starts, side="right")], next_off[starts])
    zero = np.zeros(starts.size, bool)
    zero[rising.size:rising.size + falling.size] = True
    settle = np.empty(starts.size, np.int64)
    settle[~zero] = _settle(ok, t, starts[~zero], ends[~zero])
    settle[zero] = _settle(gone, t, starts[zero], ends[zero])
    settled = settle < ends
    j = np.where(settled, settle, starts)
    peak = np.where(zero, np.nan, _signed_peak(rel_pct, starts, np.where(settled, settle + 1, ends)))
    kinds = np.concatenate([np.full(rising.size, 0), np.full(falling.size, 1), np.full(openings.size, 2)])
    close = _closings(closings, ok, t, d, rel_pct, events)
    return TransitionEvents(
        kind=np.concatenate([kinds, np.full(closings.size, 3)]),
        settled=np.concatenate([settled, np.ones(closings.size, bool)]),
        time_s=np.concatenate([np.where(settled, t[j] - t[starts], np.nan), close[0]]),
        distance_m=np.concatenate([np.where(settled, d[j] - d[starts], np.nan), close[1]]),
        peak_error_pct=np.concatenate([peak, close[2]]),
    )


def _settle(ok, t, starts, ends) -> np.ndarray:
    """For each window ``[start, end)``: the first tick from which `ok` holds for `SETTLE_HOLD_S` or to
    the window's end (an overshoot that leaves the band and comes back settles where it comes back;
    leaving the band later is a new disturbance, not this event's); ``len(ok)`` where none."""
    n = len(ok)
    ticks = np.arange(n)
    last_out = np.maximum.accumulate(np.where(ok, -1, ticks))
    next_out = np.minimum.accumulate(np.where(ok, n, ticks)[::-1])[::-1]
    # A tick from which the rate stays in the band for the hold (1 ns: the ticks' float times).
    held = ok & ((t[np.minimum(next_out, n - 1)] - t >= SETTLE_HOLD_S - 1e-9) | (next_out == n))
    next_held = np.minimum.accumulate(np.where(held, ticks, n)[::-1])[::-1]
    if not starts.size:
        return np.zeros(0, np.int64)
    tail = np.maximum(last_out[ends - 1] + 1, starts)
    return np.minimum(next_held[starts], np.where(tail < ends, tail, n))


def _signed_peak(rel_pct, starts, stops) -> np.ndarray:
    """The value of largest magnitude of `rel_pct` over each ``[start, stop)`` (NaN where none)."""
    out = np.full(starts.size, np.nan)
    for i in np.flatnonzero(stops > starts):
        part = rel_pct[starts[i]:stops[i]]
        part = part[np.isfinite(part)]
        if part.size:
            out[i] = part[np.argmax(np.abs(part))]
    return out


def _closings(closings, ok, t, d, rel_pct, events) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each closing's look back: time (s) and distance (m) from where the applied rate last left the
    band (since the event before it) to the closing, and the peak error over that stretch (the
    closing tick's own error where it closes in the band)."""
    ticks = np.arange(len(ok))
    last_in = np.maximum.accumulate(np.where(ok, ticks, -1))
    prior = np.searchsorted(events, closings, side="right") - 1
    bound = np.where(prior >= 0, np.append(events, 0)[np.maximum(prior, 0)], 0)
    tail = np.minimum(np.maximum(last_in[closings] + 1, bound), closings)
    peak = _signed_peak(rel_pct, tail, closings + 1)
    return t[closings] - t[tail], d[closings] - d[tail], peak
