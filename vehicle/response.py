"""How a real machine answers its rate controller beyond the modelled plant: its dead time, its
pass-start preset and its steady offset (``[response]`` in a scenario; `vrsim fit` finds them from a
machine's own as-applied log, `docs/twin.md`).

Real as-applied logs show a machine slower than a bench plant: a target step moves the logged rate
about a second late, and at a pass start the rate overshoots for seconds while the tractor speeds up.
Three physical causes, each one number (all zero: the plant alone, vrsim's figures as before):

* **dead time** (``dead_time_s``): transport delay inside the rate loop (the product's way from the
  valve to the flow meter, the pump's and the valve's dead band, the terminal's message to the rate
  controller). It is added to the loop plant's sensor delay, so the controller closes its loop over it
  (a controller tuned on the twin meets it) and the machine's reading, which is what it logs, shows it.
* **pass-start preset** (``startup_speed_m_s``, ``startup_hold_s``): for ``startup_hold_s`` after
  the sections open from all closed, the terminal computes its target flow at no less than
  ``startup_speed_m_s`` (the preset or "start-up speed" of rate controllers: the line is primed
  to the flow of a working speed rather than to the crawl the tractor starts at). While the tractor
  is slower, the rate on the ground is above target by the speeds' ratio.
* **steady offset** (``calibration_error_pct``): the steady ratio of what the machine applies (and
  logs) to its target, minus one, in per cent: a controller that settles inside its dead band, or a
  rate constant that differs from the one the target was computed with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common import VehicleError, check_number

__all__ = ["MachineResponse", "StartupClock"]

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
    """

    dead_time_s: float = 0.0
    startup_speed_m_s: float = 0.0
    startup_hold_s: float = 0.0
    calibration_error_pct: float = 0.0

    def __post_init__(self):
        check_number(self.dead_time_s, "dead_time_s", VehicleError, lo=0.0, hi=MAX_DEAD_TIME_S)
        check_number(self.startup_speed_m_s, "startup_speed_m_s", VehicleError, lo=0.0, hi=50.0)
        check_number(self.startup_hold_s, "startup_hold_s", VehicleError, lo=0.0, hi=MAX_HOLD_S)
        check_number(self.calibration_error_pct, "calibration_error_pct", VehicleError,
                     lo=-50.0, hi=100.0)

    @property
    def has_startup(self) -> bool:
        return self.startup_speed_m_s > 0.0 and self.startup_hold_s > 0.0

    @property
    def gain(self) -> float:
        """What the machine applies per unit of its target [-]: 1 + calibration_error_pct / 100."""
        return 1.0 + self.calibration_error_pct / 100.0


class StartupClock:
    """The pass-start preset over batches of ticks: which ticks compute their target at the preset
    speed. Causal and stateful (the time since the sections last opened), so a track stepped in
    batches of any size gives the ticks of one step over the whole track.

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

    def target_speed_m_s(self, speed_m_s, any_on) -> np.ndarray:
        """The speed each tick's target is computed at [m/s]: the sensed `speed_m_s` (m,), raised to
        the preset speed within the hold after the sections opened (`any_on`: bool (m,))."""
        v = np.asarray(speed_m_s, dtype=float)
        on = np.asarray(any_on, dtype=bool)
        if not on.size:
            return v
        prev = np.concatenate(([self.was_on], on[:-1]))
        opened = on & ~prev
        idx = np.arange(on.size, dtype=float)
        # Index of the last opening at or before each tick; before any in this batch, the carried one.
        last = np.maximum.accumulate(np.where(opened, idx, -np.inf))
        since = np.where(np.isfinite(last), idx - last, idx + 1 + self.open_ticks)
        hold = on & (since * self.period_s < self.response.startup_hold_s)
        self.was_on = bool(on[-1])
        self.open_ticks = float(since[-1])
        return np.where(hold, np.maximum(v, self.response.startup_speed_m_s), v)

    def state(self) -> dict:
        return {"was_on": self.was_on, "open_ticks": None if np.isinf(self.open_ticks) else self.open_ticks}

    def set_state(self, state: dict) -> None:
        self.was_on = bool(state["was_on"])
        self.open_ticks = np.inf if state["open_ticks"] is None else float(state["open_ticks"])
