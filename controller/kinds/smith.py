"""Kind ``smith``: a Smith predictor around the PID, for the metering shaft's and sensor's transport delay.

Smith, O. J. M. (1957), "Closer control of loops with dead time", *Chemical Engineering Progress*
53(5): 217-219; discrete form as in Astrom and Hagglund, *Advanced PID Control* (ISA, 2006),
section 7.7 "Dead-time compensation".

The predictor runs a model of the plant alongside the real one (the same lifted 50 ms model the loop
uses, fed the same current): its undelayed shaft speed at the start of the period ``y0`` and its
delayed sensor sample ``yd``. The PID acts on ``e = r - (y_m + y0 - yd)``: with a perfect model the
reading's delay cancels and the PID sees the undelayed shaft, so it can be tuned as if there were no
delay; a model error shows up as ``y_m - yd`` and is corrected by the same PID. `model_delay_s` and
`model_gain_scale` let a study mistune the model on purpose.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vrsim.controller.discretize import lift
from vrsim.controller.gains import FORMS, PidGains
from vrsim.controller.interface import LawController, LoopInfo, state_arrays
from vrsim.controller.kinds.pid import PidLaw
from vrsim.controller.lti import pid_lti, plant_lti, undelayed_lti
from vrsim.controller.params import KindParams, param
from vrsim.controller.plant import N_STATES, shaft_rev_row, shaft_rpm_row, state_space
from vrsim.controller.registry import register


@dataclass(frozen=True)
class SmithParams(KindParams):
    """Parameters of ``smith``.

    Parameters
    ----------
    kp, ki, kd : float
        The PID's gains on the predicted error (sensor volts): kp [V/V] (0.1), ki [1/s] (8.0),
        kd [s] (0). Tuned on vrsim's default plant for the delay-free loop: no overshoot of the
        per-period speed and 2 % settling in about 0.45 s after a 100 rpm step.
    form : {"incremental", "positional"}
        The PID's form, as for kind PID.
    model_delay_s : float or None
        The delay the predictor assumes [s]; None: the plant's sensor delay.
    model_gain_scale : float
        Factor on the model's valve gain (1: the plant's), to study a mistuned predictor.
    """

    KIND = "smith"
    kp: float = param(0.1, lo=0.0)
    ki: float = param(8.0, lo=0.0)
    kd: float = param(0.0, lo=0.0)
    form: str = param("incremental", choices=FORMS)
    model_delay_s: float | None = param(None, number=True, lo=0.0)
    model_gain_scale: float = param(1.0, lo=0.0, lo_open=True)

    def model(self, plant):
        """The plant model the predictor runs."""
        delay = plant.sensor_delay_s if self.model_delay_s is None else self.model_delay_s
        return replace(plant, sensor_delay_s=delay,
                       valve_flow_gain_m3_s_per_a=plant.valve_flow_gain_m3_s_per_a * self.model_gain_scale,
                       shaft_rpm_max=min(plant.shaft_rpm_max,
                                         plant.shaft_rpm_per_a * self.model_gain_scale * plant.current_max_a))


@register("smith", SmithParams, "Smith predictor around a PID for the shaft/sensor transport delay "
          "(Smith 1957)")
class Smith(LawController):
    """A PID on the Smith-predicted shaft speed; see the module docstring and `SmithParams`."""

    def __init__(self, params: SmithParams, loop: LoopInfo, n: int):
        super().__init__(params, loop, n)
        model = params.model(loop.plant)
        A, B = state_space(model)
        lifted = lift(A, B, shaft_rpm_row(model), shaft_rev_row(model), loop.control_period_s,
                      loop.control_period_s, model.sensor_delay_s)
        # [x, I] -> [x', sample]: the model's next state and its delayed sensor sample of this period
        self._next_t = np.ascontiguousarray(lifted.step[[*range(N_STATES), N_STATES + 1], :N_STATES + 1].T)
        self._c_rpm = shaft_rpm_row(model)
        self.delay_periods = lifted.delay_periods
        self.gains = PidGains(params.kp, params.ki, params.kd)
        self.pid = PidLaw(self.gains, params.form, False, loop, n)
        self.reset()

    def reset(self):
        self.pid.reset()
        # the model's [x, I] per loop, and its sensor delay line (oldest first)
        self.model_z = np.zeros(N_STATES + 1) if self.n == 1 else np.zeros((self.n, N_STATES + 1))
        self.model_delay_rpm = [0.0] * self.delay_periods if self.n == 1 else \
            np.zeros((self.n, self.delay_periods))

    def state(self):
        return {"pid_v": self.pid.mem,
                "model_x": self.model_z[..., :N_STATES].reshape(self.n, N_STATES).copy(),
                "model_delay_rpm": np.array(self.model_delay_rpm, dtype=float).reshape(
                    self.n, self.delay_periods)}

    def set_state(self, state):
        got = state_arrays(state, {"pid_v": (len(PidLaw.MEMORY), self.n), "model_x": (self.n, N_STATES),
                                   "model_delay_rpm": (self.n, self.delay_periods)}, "smith")
        self.pid.mem = got["pid_v"]
        self.model_z[..., :N_STATES] = got["model_x"][0] if self.n == 1 else got["model_x"]
        self.model_delay_rpm = got["model_delay_rpm"][0].tolist() if self.n == 1 else got["model_delay_rpm"]

    def linear_model(self):
        """The PID with its predictor as one controller from the measured error volts to output volts:
        ``C / (1 + C Ka Ks (G0 - Gd))`` with the model's undelayed and delayed responses G0, Gd."""
        import control

        info, t = self.loop, self.loop.control_period_s
        model = self.params.model(info.plant)
        inner = control.parallel(undelayed_lti(model, t), -plant_lti(model, t))
        k = info.amplifier_gain_a_per_v * info.sensor_gain_v_per_rpm
        return control.feedback(pid_lti(self.gains, t), k * inner)

    def law(self, target_rpm, measured_rpm):
        z, ring = self.model_z, self.model_delay_rpm
        if self.n == 1:
            predicted = measured_rpm + float(z[:N_STATES] @ self._c_rpm) - ring[0]
            current = self.pid.step(target_rpm, predicted)
            z[N_STATES] = current
            new = z @ self._next_t
            z[:N_STATES] = new[:N_STATES]
            ring.append(float(new[N_STATES]))
            del ring[0]
            return current
        predicted = measured_rpm + z[:, :N_STATES] @ self._c_rpm - ring[:, 0]
        current = self.pid.step(target_rpm, predicted)
        z[:, N_STATES] = current
        new = z @ self._next_t
        z[:, :N_STATES] = new[:, :N_STATES]
        ring[:, :-1] = ring[:, 1:]
        ring[:, -1] = new[:, N_STATES]
        return current
