"""A gain schedule on ground speed: a PI whose gains follow the speed the machine senses.

docs/controllers.md ("A gain schedule on ground speed") shows this file whole, and
tests/unit/test_controller_context.py runs the code shown there, so the two cannot drift.
"""

import numpy as np


class SpeedScheduledPI:
    """Feed-forward from the plant's nominal gain plus a PI in amperes per rpm whose gains are
    interpolated on ground speed between breakpoints (held beyond them; at `speed_m_s[0]` without a
    drive, when the speed is NaN)."""

    def __init__(self, params, loop, n):
        self.speeds_m_s = np.array(params.get("speed_m_s", [1.0, 4.0]), dtype=float)
        self.kp_a_per_rpm = np.array(params.get("kp_a_per_rpm", [0.003, 0.0015]), dtype=float)
        self.ki_a_per_rpm_s = np.array(params.get("ki_a_per_rpm_s", [0.012, 0.006]), dtype=float)
        if not (self.speeds_m_s.shape == self.kp_a_per_rpm.shape == self.ki_a_per_rpm_s.shape
                and np.all(np.diff(self.speeds_m_s) > 0)):
            raise ValueError(f"speed_m_s must rise and match the gains' lengths, got {params}")
        self.period_s = loop.control_period_s
        self.low_a, self.high_a = loop.current_min_a, loop.current_max_a
        self.n = n
        self.reset()

    def reset(self):
        self.error_sum_rpm = np.zeros(self.n)

    def step(self, target_rpm, measured_rpm, context):
        # a third argument: vrsim passes the context (ground speed, rate, sections, time, plant gain)
        speed = np.where(np.isnan(context.speed_m_s), self.speeds_m_s[0], context.speed_m_s)
        kp = np.interp(speed, self.speeds_m_s, self.kp_a_per_rpm)
        ki = np.interp(speed, self.speeds_m_s, self.ki_a_per_rpm_s)
        feedforward_a = target_rpm / context.shaft_rpm_per_a
        error = target_rpm - measured_rpm
        total = self.error_sum_rpm + error
        wanted = feedforward_a + kp * error + ki * self.period_s * total
        stuck = ((wanted > self.high_a) & (error > 0)) | ((wanted < self.low_a) & (error < 0))
        self.error_sum_rpm = np.where(stuck, self.error_sum_rpm, total)
        return np.clip(wanted, self.low_a, self.high_a)

    def state(self):
        return {"error_sum_rpm": self.error_sum_rpm.copy()}

    def set_state(self, state):
        self.error_sum_rpm = np.array(state["error_sum_rpm"], dtype=float)
