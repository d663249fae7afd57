"""An example of a user-defined rate controller for vrsim (see docs/controllers.md).

Use it from a scenario in this folder with::

    [controller]
    kind = "python"
    file = "my_controller.py"          # relative to the scenario file
    class = "MyController"
    params = { kp_a_per_rpm = 0.0015, ki_a_per_rpm_s = 0.008 }

vrsim calls ``MyController(params, loop, n)`` once, then ``step`` once per control period with the
targets and the speed sensor's readings of n loops (numpy arrays of shape (n,), rpm) and expects the
valve currents (A, shape (n,)). This one is a PI on the shaft speed in amperes per rpm, with clamping
anti-windup: the integral stops while the valve is saturated and the error would push it further.
Only numpy is needed (python-control for the optional ``linear_model``, which lets ``vrsim controller
analyze`` compute the loop's margins); a controller must not read clocks or draw unseeded random
numbers, so that a run is reproducible and can be saved and resumed (``state``/``set_state``).
"""

import numpy as np


class MyController:
    """PI controller: current = kp e + ki T (sum of e), e = target - measured [rpm]."""

    def __init__(self, params, loop, n):
        unknown = set(params) - {"kp_a_per_rpm", "ki_a_per_rpm_s"}
        if unknown:
            raise KeyError(f"unknown parameter {sorted(unknown)[0]!r}")
        self.kp = float(params.get("kp_a_per_rpm", 0.0015))
        self.ki = float(params.get("ki_a_per_rpm_s", 0.008))
        if self.kp < 0 or self.ki < 0:
            raise ValueError(f"gains must be >= 0, got kp_a_per_rpm={self.kp}, ki_a_per_rpm_s={self.ki}")
        self.period_s = loop.control_period_s
        self.low_a, self.high_a = loop.current_min_a, loop.current_max_a
        # amperes per rpm of error for 1 V/V: what turns these gains into the paper's volt units
        self.a_per_rpm = loop.amplifier_gain_a_per_v * loop.sensor_gain_v_per_rpm
        self.n = n
        self.reset()

    def reset(self):
        self.error_sum_rpm = np.zeros(self.n)

    def step(self, target_rpm, measured_rpm):
        error = target_rpm - measured_rpm
        total = self.error_sum_rpm + error
        wanted = self.kp * error + self.ki * self.period_s * total
        # integrate only while the valve can still follow (clamping anti-windup)
        stuck = ((wanted > self.high_a) & (error > 0)) | ((wanted < self.low_a) & (error < 0))
        self.error_sum_rpm = np.where(stuck, self.error_sum_rpm, total)
        return np.clip(wanted, self.low_a, self.high_a)

    def state(self):
        return {"error_sum_rpm": self.error_sum_rpm.copy()}

    def set_state(self, state):
        self.error_sum_rpm = np.array(state["error_sum_rpm"], dtype=float)

    def linear_model(self):
        """Optional, for `vrsim controller analyze`: the PI while unsaturated, from the error in sensor
        volts to the output in amplifier volts, C(z) = kp + ki T z / (z - 1) (a python-control system
        with dt = T)."""
        import control

        kp, ki_t = self.kp / self.a_per_rpm, self.ki * self.period_s / self.a_per_rpm
        return control.tf([kp + ki_t, -kp], [1.0, -1.0], self.period_s)
