"""Kind ``ff_pi``: feed-forward from the plant's static inverse plus a PI on the remainder.

The current is ``I = I_ff(r) + Ka u_PI``: the feed-forward ``I_ff`` is the current that holds the
target speed in steady state, taken from the model (``r / shaft_rpm_per_a``) or from a valve
calibration run on the plant as a terminal would do it (`controller.calibration`); the PI (positional,
clamping anti-windup, gains on sensor volts like the paper's PID) removes what the feed-forward gets
wrong (load torque, calibration error). Two-degree-of-freedom control with a static-inverse
feed-forward: Astrom and Murray, *Feedback Systems* (2nd ed., 2021), section 8.5 "Feedforward
design"; Astrom and Hagglund, *Advanced PID Control* (ISA, 2006), section 5.5 "Feedforward".

The sensor reports the shaft speed `reference_delay_s` late, so after a target step the reading shows
the old speed while the shaft already turns at the new one. The PI therefore compares the reading
with the target as it was that many whole control periods ago (the reference the reading can already
show), not with today's target: otherwise it would fight the feed-forward through every delay
(assumption of vrsim; with ``reference_delay_s = 0``, the target of one period ago, a 100 rpm step
settles in 1.09 s instead of 0.38 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.controller import ops
from vrsim.controller.calibration import valve_calibration
from vrsim.controller.discretize import delay_split
from vrsim.controller.gains import PidGains
from vrsim.controller.interface import LawController, LoopInfo, state_arrays
from vrsim.controller.lti import pid_lti
from vrsim.controller.params import KindParams, param
from vrsim.controller.pid_law import clamped, saturate
from vrsim.controller.registry import register

FEEDFORWARDS = ("valve_cal", "model")


@dataclass(frozen=True)
class FfPiParams(KindParams):
    """Parameters of ``ff_pi``.

    Parameters
    ----------
    feedforward : {"valve_cal", "model"}
        Where the static inverse comes from: a valve calibration run on the plant (default), or the
        model's ``shaft_rpm_per_a``.
    cal_points : int
        Currents in the valve calibration, evenly spaced over the valve's range (11).
    kp : float
        PI proportional gain [V/V] on sensor volts (0.2).
    ki : float
        PI integral gain [1/s] (2.0).
    reference_delay_s : float or None
        How late the reading is [s]; None: the plant's sensor delay (a terminal would measure it as the
        time from a current step to the reading's change). The PI's reference is the target of d
        periods ago, d as in the loop's delay line (`controller.discretize.delay_split`: 3 for the
        default 0.104 s at 50 ms).
    """

    KIND = "ff_pi"
    feedforward: str = param("valve_cal", choices=FEEDFORWARDS)
    cal_points: int = param(11, lo=2, hi=1000)
    kp: float = param(0.2, lo=0.0)
    ki: float = param(2.0, lo=0.0)
    reference_delay_s: float | None = param(None, number=True, lo=0.0)


@register("ff_pi", FfPiParams, "feed-forward from the static inverse (model or valve cal) plus a PI "
          "(Astrom and Murray 2021, 8.5)")
class FfPi(LawController):
    """Feed-forward plus PI; see the module docstring and `FfPiParams`."""

    def __init__(self, params: FfPiParams, loop: LoopInfo, n: int):
        super().__init__(params, loop, n)
        if params.feedforward == "model":
            rpm_per_a = loop.plant.shaft_rpm_per_a
            self.feedforward_a = lambda r: r / rpm_per_a
        else:
            self.cal = valve_calibration(loop, points=params.cal_points)
            self.feedforward_a = self.cal.current_for
        delay = loop.plant.sensor_delay_s if params.reference_delay_s is None else params.reference_delay_s
        # the reading at period k is the speed inside period k - d, driven by the current set for
        # the target of period k - d (`delay_split`)
        self.delay_periods = delay_split(delay, loop.control_period_s)[0]
        self.reset()

    def reset(self):
        self.error_sum_v = ops.zeros(self.n)
        # targets of the last d periods, oldest first (a list for one loop)
        self.target_history_rpm = [0.0] * self.delay_periods if self.n == 1 else \
            np.zeros((self.n, self.delay_periods))

    def state(self):
        return {"error_sum_v": ops.as_array(self.error_sum_v, self.n),
                "target_history_rpm": np.array(self.target_history_rpm, dtype=float).reshape(
                    self.n, self.delay_periods)}

    def set_state(self, state):
        got = state_arrays(state, {"error_sum_v": (self.n,),
                                   "target_history_rpm": (self.n, self.delay_periods)}, "ff_pi")
        self.error_sum_v = ops.from_array(got["error_sum_v"], self.n)
        history = got["target_history_rpm"]
        self.target_history_rpm = history[0].tolist() if self.n == 1 else history

    def linear_model(self):
        """The PI from error volts to output volts; the feed-forward and the delayed reference shape the
        response to targets but are outside the feedback loop."""
        return pid_lti(PidGains(self.params.kp, self.params.ki), self.loop.control_period_s)

    def law(self, target_rpm, measured_rpm):
        history = self.target_history_rpm
        if self.n == 1:
            reference = history[0]
            history.append(target_rpm)
            del history[0]
        else:
            reference = history[:, 0].copy()
            history[:, :-1] = history[:, 1:]
            history[:, -1] = target_rpm
        p, info = self.params, self.loop
        e = info.sensor_gain_v_per_rpm * (reference - measured_rpm)
        total = self.error_sum_v + e
        unsat = self.feedforward_a(target_rpm) + info.amplifier_gain_a_per_v * (
            p.kp * e + p.ki * info.control_period_s * total)
        frozen = clamped(unsat, e, info.current_min_a, info.current_max_a)
        self.error_sum_v = ops.where(frozen, total - e, total)
        return saturate(unsat, info.current_min_a, info.current_max_a)
