"""Kind ``pid``: the paper's P, PI and PID, incremental or positional (Liang et al. 2013, eqs. 13-17).

In a scenario this is ``kind = "P"``, ``"PI"`` or ``"PID"`` (the terms) with the keys of `PidParams`
directly in ``[controller]``, as before the registry existed. Its gains act on sensor volts
(``e = Ks (r - y_m)``) and give amplifier volts (``I = Ka u``), as in the paper's Fig. 3.

A linear PID runs on the lifted-matrix fast path (`controller.ClosedLoop`, the plant, delay line and
PID memory in one matrix product per period); `PidController` is the same law through the controller
interface, which gives the same numbers (tested to 1e-9) and is what `smith` builds on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller import ops
from vrsim.controller.gains import FORMS, GAIN_SOURCES, MAX_GAIN, TERMS, PidGains
from vrsim.controller.interface import LawController, LoopInfo, state_arrays
from vrsim.controller.loop import ClosedLoop
from vrsim.controller.lti import pid_lti
from vrsim.controller.params import KindParams, param
from vrsim.controller.pid_law import clamped, saturate
from vrsim.controller.registry import register
from vrsim.controller.tuning import gains_from_source


@dataclass(frozen=True)
class PidParams(KindParams):
    """Parameters of the ``pid`` kind (the keys of ``[controller]`` with kind P, PI or PID).

    Parameters
    ----------
    terms : {"P", "PI", "PID"}
        Which terms run (in a scenario: the ``kind`` itself).
    form : {"incremental", "positional"}
        Incremental: the paper's velocity form ``du(n) = A e(n) - B e(n-1) + C e(n-2)``; its stored
        u(n-1) is the saturated output (its anti-windup). Positional: error sum with clamping (no
        integration of an error that pushes a saturated output further).
    gains : {"paper", "textbook", "relay", "manual"}
        "paper": the paper's printed numbers (PID: A, B, C; PI: its Kp and Ki; P: its Kp).
        "textbook": Ziegler-Nichols from the paper's Ku = 0.955, Tu = 0.31 s. "relay":
        Ziegler-Nichols from an Astrom-Hagglund relay experiment on the plant. "manual": kp, ki, kd.
    kp, ki, kd : float or None
        Only with ``gains="manual"``: kp [V/V], ki [1/s], kd [s] (parallel form); ki needs terms PI or
        PID, kd terms PID.
    derivative_on_measurement : bool
        Differentiate the measured speed instead of the error (no derivative kick on target steps).
    """

    KIND = "pid"
    terms: str = param("PID", choices=TERMS)
    form: str = param("incremental", choices=FORMS)
    gains: str = param("paper", choices=GAIN_SOURCES)
    kp: float | None = param(None, number=True, lo=0.0, hi=MAX_GAIN)
    ki: float | None = param(None, number=True, lo=0.0, hi=MAX_GAIN)
    kd: float | None = param(None, number=True, lo=0.0, hi=MAX_GAIN)
    derivative_on_measurement: bool = param(False)

    def check(self) -> None:
        given = {k: getattr(self, k) for k in ("kp", "ki", "kd") if getattr(self, k) is not None}
        if self.gains != "manual":
            if given:
                name = next(iter(given))
                raise ControllerError(f"controller {name} is only used with gains='manual' "
                                      f"(gains is {self.gains!r}), got {given[name]!r}")
            return
        if "kp" not in given:
            raise ControllerError("controller kp is required with gains='manual', got None")
        if given.get("ki") and "I" not in self.terms:
            raise ControllerError(f"controller ki needs kind PI or PID (kind is {self.terms!r}), "
                                  f"got {self.ki!r}")
        if given.get("kd") and "D" not in self.terms:
            raise ControllerError(f"controller kd needs kind PID (kind is {self.terms!r}), got {self.kd!r}")

    def resolve(self, plant, control_period_s: float) -> PidGains:
        """The gains these parameters ask for (``gains="relay"`` runs the relay experiment on `plant`)."""
        return gains_from_source(self.gains, self.terms, plant, control_period_s, self.kp, self.ki, self.kd)


class PidLaw:
    """The discrete PID law for n loops (floats when n = 1), with the fast path's memory and anti-windup
    (the output stage is `controller.pid_law`'s `saturate` and `clamped`).

    Memory (volts): ``acc`` is the previous saturated output for the incremental form and the error
    sum for the positional form; ``e1, e2`` the last two errors, ``y1, y2`` the last two readings.
    """

    MEMORY = ("acc", "e1", "e2", "y1", "y2")

    def __init__(self, gains: PidGains, form: str, derivative_on_measurement: bool, info: LoopInfo, n: int):
        t = info.control_period_s
        self.kp, self.ki_t, self.kd_t = gains.kp, gains.ki * t, gains.kd / t
        self.a, self.b, self.c = gains.incremental(t)
        self.incremental = form == "incremental"
        self.dom = derivative_on_measurement
        self.ks, self.ka = info.sensor_gain_v_per_rpm, info.amplifier_gain_a_per_v
        self.ilo, self.ihi = info.current_min_a, info.current_max_a
        self.n = n
        self.reset()

    def reset(self) -> None:
        self.acc = self.e1 = self.e2 = self.y1 = self.y2 = ops.zeros(self.n)

    @property
    def mem(self) -> np.ndarray:
        """The memory as an array (5, n), rows `MEMORY` (a copy)."""
        return np.array([ops.as_array(getattr(self, k), self.n) for k in self.MEMORY])

    @mem.setter
    def mem(self, value) -> None:
        for k, row in zip(self.MEMORY, np.asarray(value, dtype=float), strict=True):
            setattr(self, k, ops.from_array(row, self.n))

    def output_v(self, e, y):
        """Unsaturated output u(n) [V] from this period's error and reading [V]."""
        if self.incremental:
            if self.dom:
                return self.acc + (self.kp + self.ki_t) * e - self.kp * self.e1 \
                    - self.kd_t * (y - 2.0 * self.y1 + self.y2)
            return self.acc + self.a * e - self.b * self.e1 + self.c * self.e2
        if self.dom:
            return self.ki_t * self.acc + (self.kp + self.ki_t) * e - self.kd_t * (y - self.y1)
        return self.ki_t * self.acc + (self.kp + self.ki_t + self.kd_t) * e - self.kd_t * self.e1

    def commit(self, e, y, unsat_a, current_a) -> None:
        """Update the memory after a period whose unsaturated and applied currents were given [A]."""
        if self.incremental:
            self.acc = current_a / self.ka
        else:
            self.acc = self.acc + ops.where(clamped(unsat_a, e, self.ilo, self.ihi), 0.0, e)
        self.e2, self.e1 = self.e1, e
        self.y2, self.y1 = self.y1, y

    def step(self, target_rpm, measured_rpm):
        """Valve current [A] for the period; updates the memory."""
        e = self.ks * (target_rpm - measured_rpm)
        y = self.ks * measured_rpm
        unsat = self.ka * self.output_v(e, y)
        current = saturate(unsat, self.ilo, self.ihi)
        self.commit(e, y, unsat, current)
        return current


def _pid_loop(params: PidParams, info: LoopInfo, n: int, record_fine: bool) -> ClosedLoop:
    return ClosedLoop(info.plant, params.resolve(info.plant, info.control_period_s), form=params.form,
                      derivative_on_measurement=params.derivative_on_measurement,
                      control_period_s=info.control_period_s, plant_step_s=info.plant_step_s, n=n,
                      record_fine=record_fine)


def _pid_batch(params_list, info: LoopInfo) -> list[tuple[list[int], ClosedLoop]]:
    """Parameter sets of one form and derivative placement share one fast-path loop, gains per loop."""
    groups: dict[tuple, list[int]] = {}
    for i, p in enumerate(params_list):
        groups.setdefault((p.form, p.derivative_on_measurement), []).append(i)
    return [(idx, ClosedLoop(info.plant, [params_list[i].resolve(info.plant, info.control_period_s)
                                          for i in idx],
                             form=form, derivative_on_measurement=dom, control_period_s=info.control_period_s,
                             plant_step_s=info.plant_step_s, n=len(idx)))
            for (form, dom), idx in groups.items()]


@register("pid", PidParams, "the paper's P/PI/PID, incremental or positional (Liang et al. 2013)",
          loop=_pid_loop, batch=_pid_batch)
class PidController(LawController):
    """The paper's PID through the controller interface (Liang et al. 2013, eqs. 13-17).

    The same law, memory and anti-windup as the fast path `controller.ClosedLoop`; see `PidParams`.
    """

    def __init__(self, params: PidParams, loop: LoopInfo, n: int):
        super().__init__(params, loop, n)
        self.gains = params.resolve(loop.plant, loop.control_period_s)
        self.pid = PidLaw(self.gains, params.form, params.derivative_on_measurement, loop, n)

    def law(self, target_rpm, measured_rpm):
        return self.pid.step(target_rpm, measured_rpm)

    def reset(self):
        self.pid.reset()

    def state(self):
        return {"pid_v": self.pid.mem}

    def set_state(self, state):
        self.pid.mem = state_arrays(state, {"pid_v": (len(PidLaw.MEMORY), self.n)}, "pid")["pid_v"]

    def linear_model(self):
        """The PID from error volts to output volts (`controller.lti.pid_lti`), for loop analysis."""
        return pid_lti(self.gains, self.loop.control_period_s)
