"""The sprayer's flow plant (controller/flow_plant.py): valve and boom physics, its step response, the
linearization the controller kinds close unchanged, and the nonlinear loop around the same controller."""

import math

import numpy as np
import pytest

from vrsim.common import ControllerError
from vrsim.controller import ControllerConfig, build_controller, build_loop, state_space, step_metrics
from vrsim.controller.discretize import zoh
from vrsim.controller.flow_plant import FlowLoop, FlowPlant, linearize_flow

Q_REF_02 = 0.8                          # an ISO 02 nozzle at 3 bar [L/min]
K_BOOM = 24 * Q_REF_02 / math.sqrt(3)   # 12 m boom, a nozzle every 0.5 m
Q0 = 15.0                               # 300 L/ha at 2.5 m/s: 0.625 L/min per nozzle, 1.83 bar
Q1 = 18.0                               # 360 L/ha: 0.75 L/min per nozzle, 2.64 bar


class _Hold:
    """A 'controller' holding one current [A] in the linearization's coordinates (open loop)."""

    def __init__(self, current_a):
        self.current_a = current_a

    def step(self, target, measured):
        return np.full(len(target), self.current_a)


def _step_targets(before=100, after=100):
    return np.r_[np.full(before, Q0), np.full(after, Q1)]


@pytest.mark.parametrize("valve", ["bypass", "inline"])
def test_valve_stroke_spans_the_nozzle_pressure_range(valve):
    fp = FlowPlant(K_BOOM, valve=valve, pressure_max_bar=5.0)
    x = np.linspace(0.0, 1.0, 101)
    q = fp.flow_l_min(x)
    assert np.all(np.diff(q) > 0)                                      # more current, more flow
    assert fp.pressure_bar(q[-1]) == pytest.approx(5.0)                # full opening: the top of the range
    shut = {"bypass": 5.0 / 25, "inline": 0.0}[valve]                  # bypass wide open: 1/5 of the flow
    assert fp.pressure_bar(q[0]) == pytest.approx(shut, abs=1e-12)
    assert fp.opening_for(Q0) == pytest.approx(np.interp(Q0, q, x), abs=1e-3)
    assert fp.flow_l_min(fp.opening_for(Q0)) == pytest.approx(Q0, rel=1e-4)


def test_opening_has_a_dead_band_and_full_stroke():
    fp = FlowPlant(K_BOOM, dead_band_a=0.1, current_max_a=1.0)
    assert fp.opening([0.0, 0.1, 0.55, 1.0, 1.5]) == pytest.approx([0.0, 0.0, 0.5, 1.0, 1.0])


@pytest.mark.parametrize("valve", ["bypass", "inline"])
def test_open_loop_step_settles_first_order(valve):
    fp = FlowPlant(K_BOOM, valve=valve, valve_time_constant_s=0.2)
    lin = linearize_flow(fp, Q0)
    loop = FlowLoop(fp, lin, _Hold(0.6 - lin.current_offset_a))      # 0.6 A held from rest (shut)
    out = loop.run(np.zeros(60))                                      # 3 s
    q = out["flow_l_min"][:, 0]
    final = float(fp.flow_l_min(fp.opening(0.6)))
    assert np.all(np.isfinite(q)) and np.all(np.diff(q) >= -1e-12)    # no NaN, no overshoot
    assert q[-1] == pytest.approx(final, rel=1e-5)                    # settled after 15 tau
    x_at_tau = fp.opening(0.6) * (1 - math.exp(-1))
    loop2 = FlowLoop(fp, lin, _Hold(0.6 - lin.current_offset_a))
    loop2.run(np.zeros(4))                                            # 4 x 50 ms = tau
    assert loop2.opening[0] == pytest.approx(x_at_tau)
    at_rest = float(fp.flow_l_min(0.0))
    assert out["true_l"].sum() == pytest.approx(np.trapezoid(np.r_[at_rest, q], dx=0.05) / 60, rel=2e-3)


@pytest.mark.parametrize("valve", ["bypass", "inline"])
def test_linearization_is_the_tangent_with_the_valve_lag(valve):
    fp = FlowPlant(K_BOOM, valve=valve, meter_gain=1.05)
    lin = linearize_flow(fp, Q0)
    assert fp.flow_l_min(fp.opening(lin.current_a)) == pytest.approx(Q0, rel=1e-4)
    for di in (-0.002, 0.002):                                        # the tangent's slope, both sides
        dq = fp.flow_l_min(fp.opening(lin.current_a + di)) - Q0
        assert dq / di == pytest.approx(lin.slope_l_min_per_a, rel=0.02)
    p = lin.plant
    assert p.shaft_rpm_per_a == pytest.approx(lin.slope_l_min_per_a * 1.05)   # metered L/min per A
    assert p.shaft_rpm_per_a * (lin.current_a - lin.current_offset_a) == pytest.approx(Q0 * 1.05)
    assert p.loop_gain_per_controller_gain() == pytest.approx(
        type(p)().loop_gain_per_controller_gain())                   # the paper plant's loop gain
    # the step response of the linear model at t = tau is the first order's 1 - 1/e (the fast poles
    # at 1 ms take a few per cent of a 200 ms lag)
    A, B = state_space(p)
    y = [p.transmission_ratio * 60 / (2 * math.pi) * (zoh(A, B, t)[1][2, 0]) / p.shaft_rpm_per_a
         for t in (0.2, 2.0)]
    assert y[0] == pytest.approx(1 - math.exp(-1), abs=0.01) and y[1] == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("valve", ["bypass", "inline"])
@pytest.mark.parametrize("kind", ["PI", "PID"])
def test_repo_pid_closes_the_flow_loop(valve, kind):
    fp = FlowPlant(K_BOOM, valve=valve)
    lin = linearize_flow(fp, Q0)
    loop = build_loop(lin.plant, ControllerConfig(kind=kind))       # the paper's gains
    out = loop.run(_step_targets())
    y = out.shaft_rpm[:, 0]
    assert np.all(np.isfinite(y))
    assert y[99] == pytest.approx(Q0, rel=1e-3)
    m = step_metrics(np.arange(100) * 0.05, (y[100:] - Q0) / (Q1 - Q0))
    assert m.overshoot_pct[0] < 5.0 and m.settling_2pct_s[0] < 3.0
    assert y[-1] == pytest.approx(Q1, rel=1e-3)
    # "shaft revolutions" are metered litres: the flow integrated over each period
    assert out.shaft_rev[-1, 0] == pytest.approx(Q1 * 0.05 / 60, rel=1e-3)


@pytest.mark.parametrize("kind", ["aog_pi", "ff_pi", "smith", "fuzzy_pid", "ideal"])
def test_other_kinds_close_it_unchanged(kind):
    lin = linearize_flow(FlowPlant(K_BOOM), Q0)
    y = build_loop(lin.plant, ControllerConfig(kind=kind)).run(_step_targets()).shaft_rpm[:, 0]
    assert np.all(np.isfinite(y))
    # aog_pi holds within its deadband and brake settings (a few per cent); the others on target
    assert y[-1] == pytest.approx(Q1, rel=0.1 if kind == "aog_pi" else 2e-3)


@pytest.mark.parametrize("valve", ["bypass", "inline"])
def test_same_controller_closes_the_nonlinear_plant(valve):
    fp = FlowPlant(K_BOOM, valve=valve, meter_gain=1.05)             # the meter reads 5 % high
    lin = linearize_flow(fp, Q0)
    target = _step_targets() * 1.05                                   # metered targets
    loop = FlowLoop(fp, lin, build_controller(ControllerConfig(kind="PI"), lin.plant))
    out = loop.run(target)
    assert np.all(np.isfinite(out["flow_l_min"]))
    assert out["measured_l_min"][99, 0] == pytest.approx(Q0 * 1.05, rel=2e-3)   # the meter on target
    assert out["flow_l_min"][-1, 0] == pytest.approx(Q1, rel=2e-3)             # the true flow lands
    m = step_metrics(np.arange(100) * 0.05, (out["flow_l_min"][100:, 0] - Q0) / (Q1 - Q0))
    assert m.overshoot_pct[0] < 5.0 and m.settling_2pct_s[0] < 3.0
    assert lin.plant.current_min_a + lin.current_offset_a == pytest.approx(fp.dead_band_a)
    assert np.all(out["current_a"] >= fp.dead_band_a - 1e-12) and np.all(out["current_a"] <= 1.0 + 1e-12)


def test_meter_error_makes_the_loop_under_apply():
    fp = FlowPlant(K_BOOM, meter_gain=1.05)
    lin = linearize_flow(fp, Q0)
    loop = FlowLoop(fp, lin, build_controller(ControllerConfig(kind="PI"), lin.plant))
    out = loop.run(np.full(200, Q0))                                  # the terminal asks Q0 of the meter
    assert out["flow_l_min"][-1, 0] == pytest.approx(Q0 / 1.05, rel=2e-3)


def test_bad_flow_plants():
    with pytest.raises(ControllerError, match="valve must be one of bypass, inline, got 'ball'"):
        FlowPlant(K_BOOM, valve="ball")
    with pytest.raises(ControllerError, match="dead_band_a must be below current_max_a"):
        FlowPlant(K_BOOM, dead_band_a=1.0)
    with pytest.raises(ControllerError, match="boom_coeff_l_min_bar"):
        FlowPlant(0.0)
    with pytest.raises(ControllerError, match="pump_flow_l_min"):
        FlowPlant(K_BOOM, pump_flow_l_min=-5.0)
    fp = FlowPlant(K_BOOM)
    with pytest.raises(ControllerError, match=r"boom flow 40\.0 L/min is outside"):
        linearize_flow(fp, 40.0)

    class WantsContext(_Hold):
        def step(self, target, measured, context):
            return super().step(target, measured)

    with pytest.raises(ControllerError, match="WantsContext.step asks for a context"):
        FlowLoop(fp, linearize_flow(fp, Q0), WantsContext(0.5))
