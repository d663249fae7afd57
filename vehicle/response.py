"""How a real machine answers its rate controller beyond the modelled plant: its dead time, its
pass-start preset and its steady offset (``[response]`` in a scenario; `vrsim fit` finds them from a
machine's own as-applied log, `docs/twin.md`).

Real as-applied logs show a machine slower than a bench plant: a target step moves the logged rate
about a second late, and at a pass start the rate overshoots for seconds while the tractor speeds up.
Four physical causes, each one or two numbers (all zero: the plant alone, vrsim's figures as before):

* **dead time** (``dead_time_s``): transport delay inside the rate loop (the product's way from the
  valve to the flow meter, the pump's and the valve's dead band, the terminal's message to the rate
  controller). It is added to the loop plant's sensor delay, so the controller closes its loop over it
  (a controller tuned on the twin meets it) and the machine's reading, which is what it logs, shows it.
* **pass-start preset** (``startup_speed_m_s``, ``startup_hold_s``): for ``startup_hold_s`` after
  the sections open from all closed, the terminal computes its target flow at no less than
  ``startup_speed_m_s`` (the preset or "start-up speed" of rate controllers: the line is primed
  to the flow of a working speed rather than to the crawl the tractor starts at). While the tractor
  is slower, the rate on the ground is above target by the speeds' ratio.
* **opening transient** (``opening_peak_pct``, ``opening_time_constant_s``): when the sections open
  from all closed, the machine puts out more (or less) than its loop's flow, the difference decaying
  exponentially: a sprayer's boom and lines refilling and its pressure built up behind the closed
  section valves, released through the nozzles (a peak above); a spreader's conveyor filling and its
  flow building up (a peak below 0, -100: nothing at first). The loop does not see it: it passes on its
  own.
* **steady offset** (``calibration_error_pct``): the steady ratio of what the machine applies (and
  logs) to its target, minus one, in per cent: a controller that settles inside its dead band, or a
  rate constant that differs from the one the target was computed with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import VehicleError, check_number

__all__ = ["MachineResponse", "PassClock"]

MAX_DEAD_TIME_S = 10.0   # beyond this a log's records are out of step with the machine, not a delay
MAX_HOLD_S = 60.0


@dataclass(frozen=True)
class MachineResponse:
    """The machine's measured response beyond its plant (see the module docstring).

    Parameters
    ----------
    dead_time_s : float
        Transport delay inside the rate loop [s], added to the loop plant's sensor delay.
    startup_speed_m_s : float
        At a pass start, the target is computed at no less than this ground speed [m/s]; 0: off.
    startup_hold_s : float
        ... for this long after the sections open from all closed [s]; 0: off.
    calibration_error_pct : float
        What the machine applies over its target, minus one [%] (the steady offset).
    opening_peak_pct : float
        At a pass start, what the machine puts out over its loop's flow [%] (-100: nothing yet) ...
    opening_time_constant_s : float
        ... decaying with this time constant [s]; 0: off.
    """

    dead_time_s: float = 0.0
    startup_speed_m_s: float = 0.0
    startup_hold_s: float = 0.0
    calibration_error_pct: float = 0.0
    opening_peak_pct: float = 0.0
    opening_time_constant_s: float = 0.0

    def __post_init__(self):
        check_number(self.dead_time_s, "dead_time_s", VehicleError, lo=0.0, hi=MAX_DEAD_TIME_S)
        check_number(self.startup_speed_m_s, "startup_speed_m_s", VehicleError, lo=0.0, hi=50.0)
        check_number(self.startup_hold_s, "startup_hold_s", VehicleError, lo=0.0, hi=MAX_HOLD_S)
        check_number(self.calibration_error_pct, "calibration_error_pct", VehicleError,
                     lo=-50.0, hi=100.0)
        check_number(self.opening_peak_pct, "opening_peak_pct", VehicleError, lo=-100.0, hi=500.0)
        check_number(self.opening_time_constant_s, "opening_time_constant_s", VehicleError, lo=0.0,
                     hi=MAX_HOLD_S)

    @property
    def has_startup(self) -> bool:
        return self.startup_speed_m_s > 0.0 and self.startup_hold_s > 0.0

    @property
    def has_opening(self) -> bool:
        return self.opening_peak_pct != 0.0 and self.opening_time_constant_s > 0.0

    @property
    def follows_passes(self) -> bool:
        """Whether anything of the response depends on the time since the sections opened."""
        return self.has_startup or self.has_opening

    @property
    def gain(self) -> float:
        """What the machine applies per unit of its target [-]: 1 + calibration_error_pct / 100."""
        return 1.0 + self.calibration_error_pct / 100.0


class PassClock:
    """Seconds since the sections last opened from all closed, tick by tick, over batches of ticks:
    what the pass-start preset and the opening transient follow. Causal and stateful, so a track
    stepped in batches of any size gives the ticks of one step over the whole track.

    Parameters
    ----------
    response : MachineResponse
    period_s : float
        Control period (one tick) [s].
    """

    def __init__(self, response: MachineResponse, period_s: float):
        self.response, self.period_s = response, float(period_s)
        self.was_on = False          # whether any section was open in the last tick
        self.open_ticks = np.inf     # ticks since the sections last opened from all closed (to the last tick)

    def since_open_s(self, any_on) -> np.ndarray:
        """Seconds since the sections opened of each tick (`any_on`: bool (m,), whether a section is
        open); inf where every section is closed. Advances the clock."""
        on = np.asarray(any_on, dtype=bool)
        if not on.size:
            return np.zeros(0)
        prev = np.concatenate(([self.was_on], on[:-1]))
        idx = np.arange(on.size, dtype=float)
        # Index of the last opening at or before each tick; before any in this batch, the carried one.
        last = np.maximum.accumulate(np.where(on & ~prev, idx, -np.inf))
        since = np.where(np.isfinite(last), idx - last, idx + 1 + self.open_ticks)
        self.was_on = bool(on[-1])
        self.open_ticks = float(since[-1])
        return np.where(on, since * self.period_s, np.inf)

    def target_speed_m_s(self, speed_m_s, since_open_s) -> np.ndarray:
        """The speed each tick's target is computed at [m/s]: the sensed `speed_m_s` (m,), raised to
        the preset speed within the hold after the sections opened."""
        r = self.response
        v = np.asarray(speed_m_s, dtype=float)
        return np.where(since_open_s < r.startup_hold_s, np.maximum(v, r.startup_speed_m_s), v)

    def opening_gain(self, since_open_s) -> np.ndarray:
        """What the machine puts out per unit of its loop's flow at each tick [-]: 1 + the opening's
        peak, decaying with its time constant after the sections opened (1 with them closed)."""
        r = self.response
        tau = max(r.opening_time_constant_s, 1e-9)
        decay = np.exp(-np.where(np.isfinite(since_open_s), since_open_s, np.inf) / tau)
        return 1.0 + r.opening_peak_pct / 100.0 * decay

    def state(self) -> dict:
        return {"was_on": self.was_on, "open_ticks": None if np.isinf(self.open_ticks) else self.open_ticks}

    def set_state(self, state: dict) -> None:
        self.was_on = bool(state["was_on"])
        self.open_ticks = np.inf if state["open_ticks"] is None else float(state["open_ticks"])
