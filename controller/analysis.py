"""Loop analysis with python-control: margins, crossover and bandwidth of a linear controller's loop.

For a kind whose controller has a linear model (``linear_model()``: ``pid``, ``ff_pi``'s PI,
``smith`` with its predictor, ``fuzzy_pid`` small-signal at zero error) the open loop, broken at the
controller's output, is

    L(z) = Ka Ks C(z) G(z)

with ``C`` the controller from error volts to output volts and ``G`` the exact pulse transfer
function current -> sensor reading of the 1 ms ZOH plant held over T, sensor delay included
(`controller.lti.plant_lti`). `analyze_loop` returns its gain and phase margins
(`control.stability_margins`), the gain-crossover ("crossover") and phase-crossover frequencies,
and the -3 dB bandwidth of the closed loop ``L / (1 + L)`` from target to reading
(`_closed_loop_bandwidth`). `services.outputs.loop_analysis` draws the Bode plot and step responses.

The saturation of the valve current is outside this small-signal view: a loop with good margins can
still wind up on large steps (``vrsim controller analyze`` plots the simulated step beside the linear one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from vrsim.common import ControllerError
from vrsim.controller import registry
from vrsim.controller.config import ControllerConfig
from vrsim.controller.discretize import delay_split
from vrsim.controller.factory import build_controller
from vrsim.controller.lti import plant_lti
from vrsim.controller.plant import PlantParams


class NotLinear(ControllerError):
    """The configuration's controller has no linear model to analyse (a nonlinear kind, the ideal
    meter, a user's class without ``linear_model``)."""


@dataclass(frozen=True)
class LoopAnalysis:
    """Margins and bandwidth of one loop (frequencies in rad/s of continuous time, up to pi / T).

    Attributes
    ----------
    kind : str
        The configuration's kind.
    gain_margin : float
        Factor by which the loop gain can grow before instability (inf: never).
    gain_margin_db : float
        The same in dB.
    phase_margin_deg : float
        Extra phase lag the loop tolerates at crossover [deg] (inf: |L| never crosses 1).
    phase_crossover_rad_s : float
        Where the phase is -180 deg and the gain margin is read [rad/s] (NaN: no crossing).
    crossover_rad_s : float
        Gain crossover, |L| = 1 [rad/s] (NaN: no crossing).
    bandwidth_rad_s : float
        Closed loop, target -> reading: first frequency 3 dB below its DC gain [rad/s].
    closed_loop_stable : bool
        All closed-loop poles inside the unit circle.
    delay_periods : int
        Whole control periods of sensor delay in the loop.
    control_period_s : float
    open_loop, closed_loop
        The python-control systems ``L`` and ``L / (1 + L)`` (dt = T), for plots and further study.
    """

    kind: str
    gain_margin: float
    gain_margin_db: float
    phase_margin_deg: float
    phase_crossover_rad_s: float
    crossover_rad_s: float
    bandwidth_rad_s: float
    closed_loop_stable: bool
    delay_periods: int
    control_period_s: float
    open_loop: object = field(repr=False, compare=False)
    closed_loop: object = field(repr=False, compare=False)

    def to_dict(self) -> dict:
        """The figures as JSON-ready values (non-finite numbers as None)."""
        out = {}
        for name in ("kind", "gain_margin", "gain_margin_db", "phase_margin_deg", "phase_crossover_rad_s",
                     "crossover_rad_s", "bandwidth_rad_s", "closed_loop_stable", "delay_periods",
                     "control_period_s"):
            value = getattr(self, name)
            out[name] = None if isinstance(value, float) and not math.isfinite(value) else value
        return out


def _open_loop(plant: PlantParams, cfg: ControllerConfig, control_period_s: float = 0.05):
    """``L(z) = Ka Ks C(z) G(z)`` of `cfg` on `plant` (a python-control system, dt = T).

    Raises `NotLinear` (a `ControllerError`) for a kind without a linear model (``aog_pi``: deadband
    and slew limit; ``ideal``: no loop; a user's class without ``linear_model``).
    """
    import control

    if registry.get(cfg.registry_kind).controller is None:
        raise NotLinear(f"controller kind {cfg.kind!r} has no controller, so no loop to analyse")
    ctrl = build_controller(cfg, plant, control_period_s, control_period_s)
    model = getattr(ctrl, "linear_model", None) or getattr(getattr(ctrl, "impl", None), "linear_model", None)
    if model is None:
        raise NotLinear(f"controller kind {cfg.kind!r} is not linear (no linear_model()): no loop analysis")
    k = plant.amplifier_gain_a_per_v * plant.sensor_gain_v_per_rpm
    return control.series(model(), k * plant_lti(plant, control_period_s))


def _closed_loop_bandwidth(closed, control_period_s: float, dbdrop: float = -3.0) -> float:
    """First frequency where the discrete system `closed`'s gain is `dbdrop` dB below its DC gain
    [rad/s] (inf: not below Nyquist).

    `control.bandwidth` of python-control 0.10.2 evaluates ``H(j w)`` also for discrete systems
    (python-control pull request #1212 fixes it after that release), so this reads the gain from
    `control.frequency_response`, which evaluates ``H(exp(j w T))``.
    """
    import control
    import numpy as np
    from scipy.optimize import brentq

    level = abs(float(np.real(closed.dcgain()))) * 10 ** (dbdrop / 20)

    def gain(w):
        return np.abs(control.frequency_response(closed, np.atleast_1d(w)).complex).ravel()

    grid = np.linspace(1e-4, math.pi / control_period_s, 4000)
    below = np.nonzero(gain(grid) < level)[0]
    if len(below) == 0:
        return math.inf
    i = below[0]
    if i == 0:
        return float(grid[0])
    return float(brentq(lambda w: gain(w)[0] - level, grid[i - 1], grid[i], xtol=1e-10))


def analyze_loop(plant: PlantParams, cfg: ControllerConfig, control_period_s: float = 0.05) -> LoopAnalysis:
    """Margins, crossovers and bandwidth of `cfg`'s loop on `plant` (see `LoopAnalysis`)."""
    import control

    loop = _open_loop(plant, cfg, control_period_s)
    gm, pm, _sm, w_pc, w_gc, _wms = control.stability_margins(loop)
    closed = control.feedback(loop, 1)
    stable = bool(all(abs(p) < 1.0 for p in closed.poles()))
    bandwidth = _closed_loop_bandwidth(closed, control_period_s) if stable else math.nan
    return LoopAnalysis(
        kind=cfg.kind, gain_margin=float(gm), gain_margin_db=20 * math.log10(gm) if gm > 0 else -math.inf,
        phase_margin_deg=float(pm), phase_crossover_rad_s=float(w_pc), crossover_rad_s=float(w_gc),
        bandwidth_rad_s=bandwidth, closed_loop_stable=stable,
        delay_periods=delay_split(plant.sensor_delay_s, control_period_s)[0],
        control_period_s=control_period_s, open_loop=loop, closed_loop=closed)
