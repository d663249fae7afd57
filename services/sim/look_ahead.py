"""How far ahead the control core looks the rate up, and the look-ahead auto-tune.

Product metered at time t lands where the implement is at ``t + delivery_delay_s``; the GNSS fix the
core reads is on average ``latency_s + 0.5 / rate_hz`` old (sample and hold at the fix rate, then the
latency); a loop that lags its target by a mean time λ meters the new rate on average λ after the
target changed. So the rate should be looked up ``L = delivery_delay_s + fix age + λ`` ahead for the
middle of each rate transition to land on the boundary (`ControlCore.targets` predicts the point
L ahead of the fix from the sensed speed, acceleration and yaw rate: `services.sim.sections.motion`).

``[controller] look_ahead_s`` chooses L (`initial_look_ahead_s`):

* unset (the default): the delivery delay, as vrsim always did (the loop's lag is left uncompensated;
  kept as the default so that existing scenarios and the accuracy library keep their figures);
* a number of seconds;
* ``"auto"``: the delivery delay plus the fix's mean age plus the loop's measured mean lag
  (`controller.response.response_time`, 30 % -> 60 % of the shaft's range and back, mean of both).
  The fix's age is vrsim's addition to what issue #13 asked for (delivery delay plus lag): a terminal
  knows it from its receiver's settings, and without it even the ideal meter switches late (on the
  default scenario its mean transition distance is 0.38 m with the delivery delay alone, 0 m with
  the fix's age added).

``[controller] look_ahead_tune = g`` (0 < g <= 1) adds the auto-tune issue #13 asks for: after each
clean rate step the look-ahead moves by g times the step's measured early/late error
(`LookAheadTuner`; the rule is vrsim's, written down there, not taken from a terminal's source).
"""

from __future__ import annotations

import math

import numpy as np

from vrsim.controller import ControllerConfig, PlantParams
from vrsim.controller.config import LOOK_AHEAD_AUTO, LOOK_AHEAD_MAX_S
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.transitions import rate_steps

TUNE_WINDOW_S = 3.0           # a step is measured over this long after it
TUNE_MIN_CHANGE = 0.05        # target change below this share of the larger level: not measured
TUNE_MIN_CHANGE_RPM = 1.0     # ... or below this many rpm


def _loop_lag_s(plant: PlantParams, cfg: ControllerConfig, control_period_s: float,
               plant_step_s: float) -> float:
    """The loop's mean lag behind its target [s] (`controller.response.ResponseTime.look_ahead_s`)."""
    from vrsim.controller.response import response_time

    return response_time(plant, cfg, control_period_s, plant_step_s).look_ahead_s


def known_delay_s(scenario: Scenario) -> float:
    """What a terminal knows it must look ahead before its loop's lag [s]: the delivery delay plus the
    GNSS fix's mean age (latency plus half the fix interval)."""
    gnss = scenario.gnss
    return scenario.implement.delivery_delay_s + gnss.latency_s + 0.5 / gnss.rate_hz


def initial_look_ahead_s(scenario: Scenario, plant: PlantParams) -> float:
    """The look-ahead [s] a run of `scenario` (with the machine's `plant`) starts with (see the module
    docstring)."""
    cfg, timing = scenario.controller, scenario.timing
    if cfg.look_ahead_s is None:
        return float(scenario.implement.delivery_delay_s)
    if cfg.look_ahead_s == LOOK_AHEAD_AUTO:
        return known_delay_s(scenario) + _loop_lag_s(plant, cfg, timing.control_period_s, timing.plant_step_s)
    return float(cfg.look_ahead_s)


class LookAheadTuner:
    """Moves the look-ahead after each clean rate step by a fraction of the measured early/late error.

    The rule, with T the control period and N = `TUNE_WINDOW_S` / T:

    1. A *rate step* at tick s is what the accuracy metrics call one (`transitions.rate_steps`), here on
       the prescription the core looked up (the terminal's own view, not the true landing point).
    2. It is measured over the ticks s .. s+N-1, if during them the implement stays on, the working
       width stays as it was at s (and at s-1), and no other rate step comes; otherwise it is dropped.
       A target that moves less than `TUNE_MIN_CHANGE` (5 %) or 1 rpm is not measured either.
    3. From the shaft's revolutions in each period (what the meter delivers; the count a shaft encoder
       gives, not the delayed speed reading), the mean speed m_k of each period; with y0 the target
       before the step and y1 the mean target over the window, the progress p_k = (m_k - y0)/(y1 - y0)
       and the step's measured lag ``lag = T sum(1 - p_k)`` (the centroid of the transition, as in
       `controller.response`).
    4. The middle of the transition landed ``e = known_delay_s + lag - L`` seconds late (early when
       negative; `known_delay_s`: delivery delay plus the fix's mean age), and the look-ahead becomes
       ``L + gain x e``, within [0, 30] s, from tick s + N on.

    With gain 1 the look-ahead is the known delay plus the last step's lag; smaller gains average
    over steps (an exponential mean with weight `gain`). The tuner sees only what a terminal sees (its
    own position estimate, targets and shaft counts): errors of the landing model stay invisible to
    it, as they would on a machine.

    State (`state`/`set_state`, plain data) carries over between batches: the look-ahead, the last
    tick's rate, target, width and implement state, and the step being measured.
    """

    def __init__(self, look_ahead_s: float, known_delay_s: float, gain: float, control_period_s: float):
        self.known_delay_s = float(known_delay_s)
        self.gain = float(gain)
        self.control_period_s = float(control_period_s)
        self.window = max(1, round(TUNE_WINDOW_S / control_period_s))
        self.look_ahead_s = float(look_ahead_s)
        self.updates = 0
        self.prev = {"rate": math.nan, "target": 0.0, "width": 0.0, "on": False}
        self.pending = None   # {"y0", "width", "target": [rpm per tick so far], "metered": [...]}

    # -- state -------------------------------------------------------------------------------------------
    def state(self) -> dict:
        """Plain data (JSON-ready except NaN)."""
        pending = self.pending
        return {"look_ahead_s": self.look_ahead_s, "updates": self.updates, "prev": dict(self.prev),
                "pending": None if pending is None else {**pending, "target": list(pending["target"]),
                                                         "metered": list(pending["metered"])}}

    def set_state(self, state: dict) -> None:
        """Restore what `state` returned."""
        self.look_ahead_s = float(state["look_ahead_s"])
        self.updates = int(state["updates"])
        prev = state["prev"]
        self.prev = {"rate": float("nan") if prev["rate"] is None else float(prev["rate"]),
                     "target": float(prev["target"]), "width": float(prev["width"]), "on": bool(prev["on"])}
        pending = state["pending"]
        self.pending = None if pending is None else {
            "y0": float(pending["y0"]), "width": float(pending["width"]),
            "target": [float(v) for v in pending["target"]],
            "metered": [float(v) for v in pending["metered"]]}

    # -- the rule ----------------------------------------------------------------------------------------
    def plan(self, rate, target, width, on) -> int | None:
        """Index in these ticks (not yet run) of the first one that will use a new look-ahead, or None.

        The caller runs the loop up to there, calls `observe` on those ticks, and looks the rest up
        again with the new look-ahead.
        """
        return self._walk(rate, target, width, on, None)

    def observe(self, rate, target, width, on, metered_rpm) -> None:
        """Advance over ticks that have run (ending at the `plan` index at the latest); a measurement
        completing on the last of them moves the look-ahead."""
        end = self._walk(rate, target, width, on, np.asarray(metered_rpm, dtype=float))
        if end is not None and end != len(rate):
            raise ValueError(f"observe: a measurement completed at tick {end - 1} of {len(rate)}: "
                             "run only up to plan()'s index")
        self.prev = {"rate": float(rate[-1]), "target": float(target[-1]), "width": float(width[-1]),
                     "on": bool(on[-1])}

    def _walk(self, rate, target, width, on, metered) -> int | None:
        """Follow the step being measured through these ticks, event by event (steps and breaks).

        Returns the index after the tick that completes a measurement, or None. With `metered` it
        also accumulates and, on completion, updates the look-ahead and clears the measurement.
        """
        m = len(rate)
        if m == 0:
            return None
        on = np.asarray(on, dtype=bool)
        width = np.asarray(width, dtype=float)
        steps = rate_steps(np.concatenate([[self.prev["rate"]], rate]),
                           np.concatenate([[self.prev["on"]], on])) - 1
        width_before = np.concatenate([[self.prev["width"]], width[:-1]])
        breaks = np.flatnonzero(~on | (width != width_before))
        pending, start, si = self.pending, 0, 0
        while True:
            if pending is None:
                if si >= len(steps):
                    break
                start, si = int(steps[si]), si + 1
                if width[start] != width_before[start]:
                    continue   # the width changed with the step: the level before is not comparable
                y0 = target[start - 1] if start > 0 else self.prev["target"]
                pending = {"y0": float(y0), "width": float(width[start]), "target": [], "metered": []}
            done = len(pending["target"])
            end = start + self.window - done
            next_step = int(steps[si]) if si < len(steps) else m
            b = np.searchsorted(breaks, start, side="right" if done == 0 else "left")
            next_break = int(breaks[b]) if b < len(breaks) else m
            if next_break < min(end, next_step, m) or next_step < min(end, m):
                pending = None     # interrupted: a break or another step comes before the window ends
                continue
            stop = min(end, m)
            if metered is not None:   # kept per tick, so the sums do not depend on the batches
                pending["target"] += np.asarray(target[start:stop], dtype=float).tolist()
                pending["metered"] += metered[start:stop].tolist()
            if end <= m:
                if metered is not None:
                    self._update(pending)
                    self.pending = None
                return end
            break
        if metered is not None:
            self.pending = pending
        return None

    def _update(self, pending: dict) -> None:
        """Move the look-ahead by the completed measurement (rule 4 of the class docstring)."""
        n, y0 = len(pending["target"]), pending["y0"]
        y1 = float(np.sum(pending["target"])) / n
        if abs(y1 - y0) < max(TUNE_MIN_CHANGE_RPM, TUNE_MIN_CHANGE * max(abs(y0), abs(y1))):
            return
        progress = (np.asarray(pending["metered"]) - y0) / (y1 - y0)
        lag_s = self.control_period_s * float(np.sum(1.0 - progress))
        error_s = self.known_delay_s + lag_s - self.look_ahead_s
        self.look_ahead_s = min(max(self.look_ahead_s + self.gain * error_s, 0.0), LOOK_AHEAD_MAX_S)
        self.updates += 1
