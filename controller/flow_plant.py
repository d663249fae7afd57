"""The sprayer's flow plant: tank -> pump -> regulating valve -> flow meter -> boom nozzles.

The paper's valve family (Liang et al. 2013: an electro-hydraulic proportional valve whose opening
follows the coil current), reduced to what a spray regulating valve needs:

* **valve**: opening ``x`` in [0, 1] follows ``x_cmd = clip((I - I_db) / (I_max - I_db), 0, 1)``
  with one time constant ``tau`` (a dead band ``I_db`` below which the spool does not move);
* **flow**: set by the opening and the nozzles' square-root law, the boom an orifice of
  ``K_b = sum(q_ref / sqrt(3 bar))`` over its open nozzles (``Q_b = K_b sqrt(p)``), ``q_ref`` a
  nozzle's flow *of the liquid sprayed* at 3 bar (its water rating times ``sqrt(1 / SG)``: the caller's,
  `vehicle.sprayer.SprayerSpec.rated_flow_l_min`; the defaults below scale with ``K_b``, so pump and
  valve keep their share of the boom's flow), the boom line's fill time neglected (it is short beside
  ``tau``):

  - ``bypass`` (in the return line of a positive-displacement pump of flow ``Q_p``; opening ``x``
    closes the bypass orifice ``(1 - x) C``): ``Q_b = Q_p K_b / (K_b + (1 - x) C)``;
  - ``inline`` (in line with the boom, the pump's relief holding ``p_s`` upstream):
    ``Q_b = K_b x C sqrt(p_s) / sqrt(K_b^2 + x^2 C^2)``;

* **flow meter**: reads ``meter_gain`` times the true flow (its calibration error), as pulses counted
  over the last control period (a delay of half a period).

Defaults size pump and valve to the boom so that the valve's stroke spans the nozzles' pressure range
(`docs/model.md`, "Sprayer").

The controller kinds close this plant unchanged through `linearize_flow`: the tangent model at an
operating flow is a `PlantParams` whose "shaft rpm" is the metered flow in L/min (and "shaft
revolutions" the metered litres); `FlowLoop` closes the same controller around the nonlinear plant (dead band,
curvature, saturation) to check that the linear design holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError, check_number, check_positive
from vrsim.controller.context import takes_context
from vrsim.controller.discretize import delay_split
from vrsim.controller.plant import RPM_PER_RAD_S, PlantParams

__all__ = ["FlowLinearization", "FlowLoop", "FlowPlant", "linearize_flow"]

VALVES = ("bypass", "inline")
FAST_POLE_S = 0.001          # the second pole of each first-order stage in PlantParams' 2nd-order slots
BYPASS_COEFF_PER_BOOM = 4.0  # fully open bypass: the boom gets 1/5 of the pump flow (1/25 of p_max)
INLINE_COEFF_PER_BOOM = 2.0  # fully open in-line valve: the boom gets 4/5 of the supply pressure
INLINE_SUPPLY_PER_P_MAX = 1.25   # ... so the supply is held at 1.25 p_max and full opening gives p_max
GRID = np.linspace(0.0, 1.0, 4001)   # openings where the flow curve is inverted


@dataclass(frozen=True)
class FlowPlant:
    """Pump, regulating valve and flow meter of a boom (see the module docstring).

    Parameters
    ----------
    boom_coeff_l_min_bar : float
        K_b, the open nozzles' flow per sqrt(bar) [L/min/bar^0.5]: N q_ref / sqrt(3), ``q_ref`` of the
        liquid sprayed (`vehicle.sprayer.SprayerSpec.rated_flow_l_min` with its density).
    valve : {"bypass", "inline"}
    pressure_max_bar : float
        Top of the nozzles' pressure range [bar]; sizes the defaults of pump and valve.
    valve_time_constant_s : float
        tau, the opening's first-order time constant [s] (*assumed*: 0.2).
    dead_band_a : float
        I_db, current below which the valve does not open [A] (*assumed*: 0.1, 10 % of the coil).
    current_max_a : float
        Current of full opening, and the coil's limit [A] (the paper's 0-1 A coil).
    meter_gain : float
        Metered litres per true litre (1 + calibration error / 100).
    meter_delay_s : float
        Delay of the meter's reading [s]: half the period its pulses are counted over (0.025).
    pump_flow_l_min : float or None
        Bypass: the pump's flow [L/min]; None: the boom's flow at `pressure_max_bar`.
    supply_pressure_bar : float or None
        In-line: the pressure held upstream of the valve [bar]; None: 1.25 `pressure_max_bar`.
    valve_coeff_l_min_bar : float or None
        C, the fully open valve's flow per sqrt(bar) [L/min/bar^0.5]; None: 4 K_b (bypass), 2 K_b (in-line).
    """

    boom_coeff_l_min_bar: float
    valve: str = "bypass"
    pressure_max_bar: float = 5.0
    valve_time_constant_s: float = 0.2
    dead_band_a: float = 0.1
    current_max_a: float = 1.0
    meter_gain: float = 1.0
    meter_delay_s: float = 0.025
    pump_flow_l_min: float | None = None
    supply_pressure_bar: float | None = None
    valve_coeff_l_min_bar: float | None = None

    def __post_init__(self):
        if self.valve not in VALVES:
            raise ControllerError(f"flow plant valve must be one of {', '.join(VALVES)}, got {self.valve!r}")
        for name in ("boom_coeff_l_min_bar", "pressure_max_bar", "valve_time_constant_s", "current_max_a",
                     "meter_gain"):
            check_positive(getattr(self, name), f"flow plant {name}", ControllerError)
        check_number(self.dead_band_a, "flow plant dead_band_a", ControllerError, lo=0.0)
        if self.dead_band_a >= self.current_max_a:
            raise ControllerError(f"flow plant dead_band_a must be below current_max_a "
                                  f"({self.current_max_a!r}), got {self.dead_band_a!r}")
        check_number(self.meter_delay_s, "flow plant meter_delay_s", ControllerError, lo=0.0)
        kb, p_max = self.boom_coeff_l_min_bar, self.pressure_max_bar
        per_boom = BYPASS_COEFF_PER_BOOM if self.valve == "bypass" else INLINE_COEFF_PER_BOOM
        for name, default in (("pump_flow_l_min", kb * math.sqrt(p_max)),
                              ("supply_pressure_bar", INLINE_SUPPLY_PER_P_MAX * p_max),
                              ("valve_coeff_l_min_bar", per_boom * kb)):
            value = getattr(self, name)
            object.__setattr__(self, name, default if value is None
                               else check_positive(value, f"flow plant {name}", ControllerError))

    def opening(self, current_a):
        """Steady opening [0-1] that `current_a` [A] commands (dead band, then linear to full)."""
        span = self.current_max_a - self.dead_band_a
        return np.clip((np.asarray(current_a, float) - self.dead_band_a) / span, 0.0, 1.0)

    def flow_l_min(self, opening):
        """True boom flow [L/min] at valve `opening` [0-1]."""
        x = np.asarray(opening, float)
        kb, c = self.boom_coeff_l_min_bar, self.valve_coeff_l_min_bar
        if self.valve == "bypass":
            return self.pump_flow_l_min * kb / (kb + (1.0 - x) * c)
        return kb * x * c * math.sqrt(self.supply_pressure_bar) / np.sqrt(kb**2 + (x * c) ** 2)

    def pressure_bar(self, flow_l_min):
        """Boom (nozzle) pressure [bar] at boom flow `flow_l_min` [L/min]."""
        return (np.asarray(flow_l_min, float) / self.boom_coeff_l_min_bar) ** 2

    def flow_range_l_min(self) -> tuple[float, float]:
        """Boom flow [L/min] with the valve shut and fully open."""
        return float(self.flow_l_min(0.0)), float(self.flow_l_min(1.0))

    def opening_for(self, flow_l_min: float) -> float:
        """The opening [0-1] that gives `flow_l_min`; a `ControllerError` outside the valve's range."""
        lo, hi = self.flow_range_l_min()
        if not (lo < flow_l_min < hi):
            raise ControllerError(f"flow plant: boom flow {flow_l_min!r} L/min is outside what the "
                                  f"{self.valve} valve can set ({lo:.4g} to {hi:.4g} L/min)")
        return float(np.interp(flow_l_min, self.flow_l_min(GRID), GRID))


@dataclass(frozen=True)
class FlowLinearization:
    """The flow plant's tangent model at an operating point, in `PlantParams`' form.

    Attributes
    ----------
    plant : PlantParams
        The loop's plant: "shaft rpm" is the metered flow [L/min], "shaft rev" the metered litres, the
        current the valve current minus `current_offset_a`. Build loops with ``build_loop(plant, cfg)``.
    flow_l_min : float
        The operating point's true boom flow [L/min].
    current_a : float
        The valve current that holds it [A].
    current_offset_a : float
        Real valve current = loop current + this [A] (the tangent's zero crossing).
    slope_l_min_per_a : float
        d(true flow)/d(current) at the operating point [L/min/A].
    """

    plant: PlantParams
    flow_l_min: float
    current_a: float
    current_offset_a: float
    slope_l_min_per_a: float


def linearize_flow(fp: FlowPlant, flow_l_min: float) -> FlowLinearization:
    """The tangent model of `fp` at true boom flow `flow_l_min` [L/min] as a `PlantParams`.

    Valve: ``(tau s + 1)(eps s + 1)`` in the valve's 2nd-order slot, the "motor" ``(eps s + 1)^2``
    (eps = 1 ms, poles 50x faster than the 50 ms loop: the flow is algebraic in the opening); the
    DC gain is the tangent's slope times the meter's gain; the current limits are the valve's stroke
    [dead band, full] shifted by the offset; the sensor gain makes the loop's gain the paper plant's
    (`PlantParams.loop_gain_per_controller_gain`), so the paper's PID gains act on the same loop gain;
    the sensor delay is the meter's.
    """
    x0 = fp.opening_for(flow_l_min)
    span_a = fp.current_max_a - fp.dead_band_a
    h = 1e-6
    x_lo, x_hi = max(x0 - h, 0.0), min(x0 + h, 1.0)
    slope = float(fp.flow_l_min(x_hi) - fp.flow_l_min(x_lo)) / (x_hi - x_lo) / span_a
    current = fp.dead_band_a + x0 * span_a
    offset = current - flow_l_min / slope
    gain = slope * fp.meter_gain                        # metered L/min per A
    i_min, i_max = fp.dead_band_a - offset, fp.current_max_a - offset
    tau, eps = fp.valve_time_constant_s, FAST_POLE_S
    paper_loop_gain = PlantParams().loop_gain_per_controller_gain()
    ka = PlantParams().amplifier_gain_a_per_v
    plant = PlantParams(
        amplifier_gain_a_per_v=ka, valve_flow_gain_m3_s_per_a=1.0,
        valve_natural_freq_rad_s=1.0 / math.sqrt(tau * eps),
        valve_damping=(tau + eps) / (2 * math.sqrt(tau * eps)),
        motor_natural_freq_rad_s=1.0 / eps, motor_damping=1.0,
        motor_displacement_m3_per_rad=RPM_PER_RAD_S / gain, transmission_ratio=1.0,
        current_min_a=i_min, current_max_a=i_max,
        # the top target: full opening, or where the tangent meets the stroke (less round-off)
        shaft_rpm_max=min(fp.flow_range_l_min()[1] * fp.meter_gain, gain * i_max) * (1.0 - 1e-9),
        sensor_gain_v_per_rpm=paper_loop_gain / (ka * gain), sensor_delay_s=fp.meter_delay_s)
    return FlowLinearization(plant, float(flow_l_min), current, offset, slope)


class FlowLoop:
    """n loops of the nonlinear flow plant closed by a controller built for its linearization.

    Per control period: the controller gets the target and the meter's delayed reading (metered
    L/min), its current (in the linearization's coordinates) is shifted by the offset and clipped to
    the coil, and the opening follows it exactly (first order) over the period.

    Parameters
    ----------
    fp : FlowPlant
    lin : FlowLinearization
        Where the controller was designed (its offset maps currents).
    controller
        A controller of ``lin.plant`` for n loops (``controller.build_controller(cfg, lin.plant)``) whose
        ``step`` takes target and reading only (the built-in kinds; no drive context here).
    control_period_s : float
    n : int
    substeps : int
        Points per period where the flow is evaluated to integrate the litres (trapezoids).
    """

    def __init__(self, fp: FlowPlant, lin: FlowLinearization, controller, control_period_s: float = 0.05,
                 n: int = 1, substeps: int = 10):
        if takes_context(controller.step):
            raise ControllerError("FlowLoop runs controllers whose step takes (target, measured); "
                                  f"{type(controller).__name__}.step asks for a context")
        self.fp, self.lin, self.controller, self.n = fp, lin, controller, n
        self.control_period_s = check_positive(control_period_s, "control_period_s", ControllerError)
        delay_periods, offset_s = delay_split(fp.meter_delay_s, control_period_s) if fp.meter_delay_s > 0 \
            else (1, control_period_s)
        self._read_at_s = offset_s            # reading: flow at this offset into period k - d
        self._ring = np.zeros((delay_periods, n))
        self._t_s = np.linspace(0.0, control_period_s, substeps + 1)
        self.opening = np.zeros(n)

    def run(self, targets_l_min) -> dict[str, np.ndarray]:
        """Advance one period per row of `targets_l_min` ((K,) or (K, n), metered L/min).

        Returns
        -------
        dict of ndarray, shape (K, n)
            ``flow_l_min`` true flow at each period's end, ``true_l`` true litres over the period,
            ``measured_l_min`` the reading the controller used, ``current_a`` the real valve current.
        """
        t = np.asarray(targets_l_min, float).reshape(len(targets_l_min), -1) * np.ones(self.n)
        out = {k: np.empty_like(t) for k in ("flow_l_min", "true_l", "measured_l_min", "current_a")}
        tau = self.fp.valve_time_constant_s
        decay = np.exp(-self._t_s / tau)[:, None]                  # (S + 1, 1)
        read_decay = math.exp(-self._read_at_s / tau)
        lo, hi = self.lin.plant.current_min_a, self.lin.plant.current_max_a
        for k, target in enumerate(t):
            measured = self._ring[0].copy()
            current = np.clip(np.asarray(self.controller.step(target, measured), float), lo, hi) \
                + self.lin.current_offset_a
            x_cmd = self.fp.opening(current)
            x = x_cmd + (self.opening - x_cmd) * decay              # (S + 1, n) openings in the period
            q = self.fp.flow_l_min(x)
            x_read = x_cmd + (self.opening - x_cmd) * read_decay
            self._ring = np.vstack([self._ring[1:], self.fp.meter_gain * self.fp.flow_l_min(x_read)])
            self.opening = x[-1]
            out["flow_l_min"][k], out["measured_l_min"][k], out["current_a"][k] = q[-1], measured, current
            out["true_l"][k] = np.trapezoid(q, self._t_s, axis=0) / 60.0
        return out
