"""Kind ``aog_pi``: the normalised PI of AgOpenGPS's RateController, with its default settings.

Source: the RateController project (github.com/SK21/AOG_RC, read at commit 6af548b9, August 2026):
the Teensy rate module's ``Modules/Teensy Rate/RCteensy/PID.ino`` (function ``PIDmotor``), its
decoding of the settings in ``Receive.ino`` (PGN 32502), the defaults in the PC application's
``RateAppSource/RateController/Classes/Props.cs`` ("flow adjustment defaults") and the rationale in
``RateAppSource/docs/PID_Normalized_Control_Rationale.md``. Re-implemented from that description,
vectorised over n loops; no code was copied.

Each PID run (every `pid_period_s`, RateController's ``PIDtime``) with a positive target:

* the reference rate is the highest target seen while enabled (latched, reset when the target is 0);
* the error ``target - measured`` is reset-tested against the deadband: crossing to the other side
  by more than the deadband clears the integral (integral reset on overshoot);
* inside the deadband (``|error| <= deadband x target``) nothing changes and the integral is cleared;
* otherwise the error, clamped to +-target, as a fraction of the reference rate, ``f``;
  "near target" is ``|f| <= brake point``: only there does the integral accumulate, by at most
  ``max_integral`` PWM counts per run; the proportional part is slowed to ``slow_adjust`` there;
* the change ``f Kp 0.1 brake x authority + integral`` is limited to +-``slew_rate`` PWM counts and
  added to the output (the "motor" control type: the PWM sets the drive speed), which is kept within
  ``[min PWM, max PWM]``. Between runs the output holds; with a zero target it is 0 and the last
  output is kept for the restart.

RateController's "valve" control type is not offered: it drives a motorised flow-control valve whose
PWM moves the valve (an integrating actuator); this plant's valve current sets the motor speed, the
"motor" type's physics.

Assumption (not in the source): the 8-bit PWM duty (0-255) maps linearly onto the valve current range
``[current_min_a, current_max_a]`` (a PWM valve driver with current feedback).
"""

from __future__ import annotations

from dataclasses import dataclass

from vrsim.common import ControllerError
from vrsim.controller import ops
from vrsim.controller.interface import LawController, LoopInfo
from vrsim.controller.params import KindParams, param
from vrsim.controller.registry import register

PWM_FULL = 255.0        # 8-bit PWM: Receive.ino scales the percentages to 0-255
KP_SCALE = 0.1          # PID.ino's MotorKpScale: the motor path accumulates its change every run
KI_SCALE = 0.01         # PID.ino's MotorKiScale


@dataclass(frozen=True)
class AogPiParams(KindParams):
    """Parameters of ``aog_pi``; defaults are RateController's (Props.cs, decoded as Receive.ino does).

    Parameters
    ----------
    kp_slider_pct, ki_slider_pct : float
        The proportional and integral sliders of RateController's control menu, 0-100 (Kp = 40 / 100,
        Ki = 60 / 100 by default; the firmware multiplies them by its motor scales 0.1 and 0.01).
    deadband_pct : float
        Error (% of the target) within which nothing is adjusted and the integral is cleared (1.5).
    brake_point_pct : float
        Error (% of the reference rate) below which the loop is "near target": integral on, slow
        proportional adjustment (35).
    slow_adjust_pct : float
        The proportional adjustment near target, % of normal (60).
    slew_rate_pwm_per_run : float
        Largest output change per PID run, in PWM counts of 255 (25).
    max_integral_pwm_per_run : float
        Largest integral change per PID run, in PWM counts of 255 (25.0; the app sends 250 = x10).
    min_pwm_pct, max_pwm_pct : float
        Output limits while running, % of full PWM (5 and 100).
    pid_period_s : float
        Time between PID runs (RateController's PIDtime, 150 ms); the output holds in between. Runs
        happen at the first control period at least this long after the previous one.
    """

    KIND = "aog_pi"
    kp_slider_pct: float = param(40.0, lo=0.0, hi=100.0)
    ki_slider_pct: float = param(60.0, lo=0.0, hi=100.0)
    deadband_pct: float = param(1.5, lo=0.0, hi=100.0)
    brake_point_pct: float = param(35.0, lo=0.0, hi=100.0)
    slow_adjust_pct: float = param(60.0, lo=0.0, hi=100.0)
    slew_rate_pwm_per_run: float = param(25.0, lo=0.0, hi=PWM_FULL, lo_open=True)
    max_integral_pwm_per_run: float = param(25.0, lo=0.0, hi=PWM_FULL)
    min_pwm_pct: float = param(5.0, lo=0.0, hi=100.0)
    max_pwm_pct: float = param(100.0, lo=0.0, hi=100.0)
    pid_period_s: float = param(0.15, lo=0.0, lo_open=True)

    def check(self) -> None:
        if self.max_pwm_pct <= self.min_pwm_pct:
            raise ControllerError(f"controller aog_pi max_pwm_pct must exceed min_pwm_pct "
                                  f"({self.min_pwm_pct!r}), got {self.max_pwm_pct!r}")


@register("aog_pi", AogPiParams, "AgOpenGPS RateController's normalised PI with deadband, slow band, "
          "slew and integral limits (SK21/AOG_RC PID.ino)")
class AogPi(LawController):
    """AgOpenGPS RateController's motor PI (``PIDmotor``), see the module docstring and `AogPiParams`."""

    MEMORY = ("pwm", "integral_pwm", "reference_rpm", "error_positive", "since_run_s")

    def __init__(self, params: AogPiParams, loop: LoopInfo, n: int):
        super().__init__(params, loop, n)
        p = params
        self.min_pwm = PWM_FULL * p.min_pwm_pct / 100.0
        self.max_pwm = PWM_FULL * p.max_pwm_pct / 100.0
        self.authority = max(self.max_pwm - self.min_pwm, 1.0)
        # per-run constants of PIDmotor, in PWM counts per unit of the error fraction
        self.kp_pwm = p.kp_slider_pct / 100.0 * KP_SCALE * self.authority
        self.ki_pwm = p.ki_slider_pct / 100.0 * KI_SCALE * self.authority
        self.slow = p.slow_adjust_pct / 100.0
        self.brake = p.brake_point_pct / 100.0
        self.deadband = p.deadband_pct / 100.0
        self.due_s = p.pid_period_s - 1e-9
        self.amps_per_pwm = (loop.current_max_a - loop.current_min_a) / PWM_FULL
        self.reset()

    def reset(self):
        # since_run_s starts "long ago", so the first enabled period runs the PI at once (as millis()
        # - LastCheck does on the module); error_positive starts true, as in PID.ino.
        self.pwm = self.integral_pwm = self.reference_rpm = ops.zeros(self.n)
        self.error_positive = ops.full(self.n, 1.0)
        self.since_run_s = ops.full(self.n, self.params.pid_period_s)

    def law(self, target_rpm, measured_rpm):
        enabled = target_rpm > 0.0
        since = self.since_run_s + self.loop.control_period_s
        if not ops.all_(enabled):     # PID disabled: integral and reference rate cleared, last PWM kept
            self.integral_pwm = ops.where(enabled, self.integral_pwm, 0.0)
            self.reference_rpm = ops.where(enabled, self.reference_rpm, 0.0)
        due = enabled & (since >= self.due_s)
        if ops.any_(due):
            self._run(due, target_rpm, measured_rpm)
            since = ops.where(due, 0.0, since)
        self.since_run_s = since
        pwm = ops.where(enabled, self.pwm, 0.0)
        return self.loop.current_min_a + self.amps_per_pwm * pwm

    def _run(self, due, target, measured):
        """One PID run on the loops in `due` (PID.ino's PIDmotor body)."""
        p = self.params
        ref = ops.where(due, ops.maximum(self.reference_rpm, target), self.reference_rpm)
        error = target - measured
        band = self.deadband * target
        positive = self.error_positive > 0.5
        flip = due & (((error > band) & ops.not_(positive)) | ((error < -band) & positive))
        positive = positive ^ flip
        integral = ops.where(flip, 0.0, self.integral_pwm)
        active = due & (ops.absolute(error) > band)
        frac = ops.clip(error, -target, target) / ops.where(ref > 0.0, ref, 1.0)
        near = ops.absolute(frac) <= self.brake
        grown = integral + ops.clip(frac * self.ki_pwm, -p.max_integral_pwm_per_run,
                                    p.max_integral_pwm_per_run)
        grown = ops.where(near, grown, integral) if self.ki_pwm > 0.0 else ops.zeros(self.n)
        grown = ops.clip(grown, -self.authority, self.authority)
        change = ops.clip(frac * self.kp_pwm * ops.where(near, self.slow, 1.0) + grown,
                          -p.slew_rate_pwm_per_run, p.slew_rate_pwm_per_run)
        moved = ops.clip(self.pwm + change, self.min_pwm, self.max_pwm)
        self.pwm = ops.where(active, moved, self.pwm)
        self.integral_pwm = ops.where(active, grown, ops.where(due, 0.0, integral))
        self.reference_rpm = ref
        self.error_positive = ops.where(positive, 1.0, 0.0)
