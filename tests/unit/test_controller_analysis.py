"""Loop analysis against python-control on independently built systems, and the response-time
measurement against known answers."""

import math
from dataclasses import replace

import control
import numpy as np
import pytest

from tests.unit.test_controller_plant import paper_tf
from vrsim.common import ControllerError
from vrsim.controller import ControllerConfig, PlantParams, simulate, ultimate_from_pulse, unlimited
from vrsim.controller.analysis import NotLinear, analyze_loop
from vrsim.controller.factory import resolve_gains
from vrsim.controller.response import response_time

P = PlantParams()
T = 0.05


def independent_open_loop(plant, cfg, whole_periods):
    """Ka Ks C(z) z^-m G_zoh(z) from the paper's continuous transfer functions, python-control's own ZOH
    and a textbook PID: the loop for a sensor delay of m + 1 whole periods minus one period
    (`delay_split` puts a delay of exactly m T at the end of period k - m - 1)."""
    g = control.sample_system(paper_tf(plant), T, method="zoh")
    gains = resolve_gains(cfg, plant, T)
    z = control.tf([1.0, 0.0], [1.0], T)
    pid = gains.kp + gains.ki * T * z / (z - 1) + gains.kd / T * (z - 1) / z
    delay = control.tf([1.0], [1.0] + [0.0] * whole_periods, T)
    return plant.amplifier_gain_a_per_v * plant.sensor_gain_v_per_rpm * pid * delay * g


@pytest.mark.parametrize("cfg", [
    ControllerConfig(kind="PI"), ControllerConfig(kind="PI", gains="textbook"),
    ControllerConfig(kind="PID", gains="manual", kp=0.3, ki=1.5, kd=0.004), ControllerConfig(kind="P"),
])
def test_margins_agree_with_python_controls_margin_on_the_same_loop(cfg):
    plant = replace(P, sensor_delay_s=0.1)      # exactly two periods: z^-2 G_zoh(z)
    ours = analyze_loop(plant, cfg, T)
    gm, pm, w_pc, w_gc = control.margin(independent_open_loop(plant, cfg, 2))
    assert ours.gain_margin == pytest.approx(gm, rel=1e-6)
    assert ours.phase_crossover_rad_s == pytest.approx(w_pc, rel=1e-6)
    if math.isfinite(pm):
        assert ours.phase_margin_deg == pytest.approx(pm, rel=1e-6)
        assert ours.crossover_rad_s == pytest.approx(w_gc, rel=1e-6)
    else:
        assert math.isinf(ours.phase_margin_deg)       # P at 0.6 Ku: |L| < 1 everywhere


def test_p_loop_gain_margin_is_the_ultimate_gain_over_kp():
    ku, tu = ultimate_from_pulse(P, T)
    a = analyze_loop(P, ControllerConfig(kind="P"))
    assert a.gain_margin == pytest.approx(ku / 0.573, rel=1e-6)
    assert a.phase_crossover_rad_s == pytest.approx(2 * math.pi / tu, rel=1e-6)
    assert a.delay_periods == 3 and a.closed_loop_stable


@pytest.mark.parametrize("kind", ["PI", "smith"])
def test_analysed_closed_loop_is_the_simulated_loop_without_saturation(kind):
    cfg = ControllerConfig(kind=kind)
    a = analyze_loop(P, cfg)
    linear = control.step_response(a.closed_loop, T=np.arange(60) * T)
    sim = simulate(unlimited(P), cfg, 10.0, 3.0)
    np.testing.assert_allclose(10.0 * np.ravel(linear.outputs), sim.measured_rpm[:, 0], atol=1e-9)
    # bandwidth: the closed loop's gain is 3 dB down there
    gain = abs(control.frequency_response(a.closed_loop, [a.bandwidth_rad_s]).complex.ravel()[0])
    assert gain == pytest.approx(abs(a.closed_loop.dcgain()) * 10 ** (-3 / 20), rel=1e-6)


def test_every_linear_kind_has_margins_and_the_others_say_why_not():
    for kind in ("PID", "ff_pi", "smith", "fuzzy_pid"):
        a = analyze_loop(P, ControllerConfig(kind=kind))
        assert a.closed_loop_stable and a.gain_margin > 1.4 and a.phase_margin_deg > 25, kind
        assert set(a.to_dict()) >= {"gain_margin", "phase_margin_deg", "crossover_rad_s", "bandwidth_rad_s"}
    with pytest.raises(NotLinear, match="'aog_pi' is not linear"):
        analyze_loop(P, ControllerConfig(kind="aog_pi"))
    with pytest.raises(NotLinear, match="'ideal' has no controller, so no loop"):
        analyze_loop(P, ControllerConfig(kind="ideal"))


def test_ideal_meter_has_no_response_time():
    r = response_time(P, ControllerConfig(kind="ideal"))
    assert r.up.mean_lag_s == 0.0 and r.down.mean_lag_s == 0.0 and r.up.t50_s == 0.0
    assert r.look_ahead_s == 0.0


def test_open_loop_feedforward_lags_by_the_plants_first_moment():
    # no feedback: the metered product lags by -G'(0)/G(0) = 2 zv/wv + 2 zh/wh of the paper's plant
    cfg = ControllerConfig(kind="ff_pi", params={"feedforward": "model", "kp": 0.0, "ki": 0.0})
    r = response_time(P, cfg)
    want = 2 * 0.57 / 335.2 + 2 * 0.12 / 183.6
    assert r.up.mean_lag_s == pytest.approx(want, rel=1e-6)
    assert r.down.mean_lag_s == pytest.approx(want, rel=1e-6)


def test_response_times_order_the_kinds_as_their_step_responses_do():
    lag = {k: response_time(P, ControllerConfig(kind=k)).look_ahead_s for k in ("PID", "smith", "aog_pi")}
    assert 0.25 < lag["PID"] < 0.35          # the paper's PID: about 0.30 s on vrsim's default plant
    assert lag["smith"] < 0.5 * lag["PID"]
    assert lag["aog_pi"] > 1.0                # RateController's defaults are slow on purpose
    with pytest.raises(ControllerError, match="low_rpm < high_rpm"):
        response_time(P, ControllerConfig(), low_rpm=150.0, high_rpm=100.0)
