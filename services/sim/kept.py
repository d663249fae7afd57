"""What a run keeps of its ticks for the pictures and the as-applied log, tick by tick or at once.

A run accounted part by part (`services.sim.bounded`) keeps no per-tick arrays: it hands each part to
these as it goes, and they keep what their outputs show, bounded: the path over the prescription,
thinned to at most about `MAX_TRACK_POINTS` points (map.png), and a minute of the series from 10 s
before the first rate step (timeseries.png). The in-process run gives them its whole track at once, so
both draw the same (`services.sim.run.RunResult.kept`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vrsim.services.sim.transitions import rate_steps

TIMESERIES_WINDOW_S = 60.0   # timeseries.png's minute ...
TIMESERIES_BEFORE_S = 10.0   # ... from this long before the first rate step (else the run's start)
MAX_TRACK_POINTS = 20_000  # the path over the prescription: more points draw the same line
SERIES_KEYS = ("time_s", "target_shaft_rpm", "shaft_rpm", "prescribed_kg_ha", "applied_kg_ha")


class SeriesWindow:
    """timeseries.png's window: `TIMESERIES_WINDOW_S` of the series from `TIMESERIES_BEFORE_S` before
    the first rate step under the landing point (`services.sim.transitions.rate_steps`; none: from the
    run's first tick), fed in consecutive parts (`add`); ``series`` holds it (`SERIES_KEYS`)."""

    def __init__(self):
        self.series: dict | None = None   # the window so far, once its start is known
        # Before the first step: the last `TIMESERIES_BEFORE_S` (and the first minute).
        self._recent: dict | None = None
        self._last = None   # (prescribed, on) of the last tick seen: a step across parts
        self._done = False

    def add(self, columns: dict, implement_on) -> None:
        """The next ticks: `SERIES_KEYS` arrays of one length, and whether the implement was on."""
        if self._done:
            return
        on = np.asarray(implement_on, bool)
        if self.series is not None:
            self._extend(columns)
            return
        rx, head = columns["prescribed_kg_ha"], 0
        if self._last is not None:
            rx, on, head = np.append(self._last[0], rx), np.append(self._last[1], on), 1
        steps = rate_steps(rx, on) - head
        if len(columns["time_s"]):
            self._last = (columns["prescribed_kg_ha"][-1], on[-1])
        seen = _joined(self._recent, columns)
        if not steps.size:
            t = seen["time_s"]
            keep = (t >= t[-1] - TIMESERIES_BEFORE_S) | (t < t[0] + TIMESERIES_WINDOW_S) if t.size else t
            self._recent = {k: v[keep] for k, v in seen.items()}
            return
        at = len(seen["time_s"]) - len(columns["time_s"]) + int(steps[0])
        t = seen["time_s"]
        i0 = int(np.searchsorted(t, t[at] - TIMESERIES_BEFORE_S))
        self._recent, self.series = None, {k: v[i0:i0 + 1] for k, v in seen.items()}
        self._extend({k: v[i0 + 1:] for k, v in seen.items()})

    @property
    def complete(self) -> bool:
        """The window's minute is whole: what comes next changes nothing of it."""
        return self._done

    def finish(self) -> dict:
        """The window (from the run's first tick if no step came)."""
        if self.series is None:
            seen = self._recent or {k: np.zeros(0) for k in SERIES_KEYS}
            self.series, self._done = {k: v[:1] for k, v in seen.items()}, False
            self._extend({k: v[1:] for k, v in seen.items()})
        return self.series

    def _extend(self, columns: dict) -> None:
        """Add ticks to the window while they fall within its minute."""
        t0 = self.series["time_s"][0]
        end = int(np.searchsorted(columns["time_s"], t0 + TIMESERIES_WINDOW_S))
        self.series = _joined(self.series, {k: v[:end] for k, v in columns.items()})
        self._done = end < len(columns["time_s"])


def _joined(a: dict | None, b: dict) -> dict:
    return dict(b) if a is None else {k: np.concatenate([a[k], b[k]]) for k in b}


@dataclass
class PathPoints:
    """The path over the prescription: every `stride`-th tick's position (x, y), m, counted from the
    run's first tick, fed in consecutive parts (`add`)."""

    stride: int
    x_m: list = field(default_factory=list)
    y_m: list = field(default_factory=list)
    ticks: int = 0

    @classmethod
    def for_ticks(cls, ticks: int) -> PathPoints:
        """Thinned to at most about `MAX_TRACK_POINTS` points over `ticks` ticks (an estimate ahead of a
        drive: a longer one draws more points)."""
        return cls(max(1, int(ticks) // MAX_TRACK_POINTS))

    def add(self, x_m, y_m) -> None:
        first = (-self.ticks) % self.stride
        self.x_m.append(np.asarray(x_m)[first::self.stride])
        self.y_m.append(np.asarray(y_m)[first::self.stride])
        self.ticks += len(x_m)

    def xy(self) -> tuple[np.ndarray, np.ndarray]:
        return (np.concatenate(self.x_m) if self.x_m else np.zeros(0),
                np.concatenate(self.y_m) if self.y_m else np.zeros(0))


@dataclass
class Kept:
    """What the outputs need of a run's ticks beyond its accounts: the path points (`PathPoints.xy`),
    timeseries.png's window (`SeriesWindow`) and the as-applied log (`maps.PointLog`, thinned to
    ``[output] log_rate_hz``)."""

    path_xy: tuple[np.ndarray, np.ndarray]
    series: dict
    point_log: object
