"""The plant against the paper's formulas and an independent python-control build of its transfer
functions."""

import math

import control
import numpy as np
import pytest

from vrsim.common import ControllerError
from vrsim.controller import PlantParams, state_space
from vrsim.controller.discretize import zoh
from vrsim.controller.plant import RPM_PER_RAD_S, shaft_rpm_row

P = PlantParams()


def paper_tf(p=P):
    """Current [A] -> shaft speed [rpm], straight from eqs. 2 and 11 (speed = s * angle)."""
    wv, wh = p.valve_natural_freq_rad_s, p.motor_natural_freq_rad_s
    valve = control.tf([p.valve_flow_gain_m3_s_per_a], [1 / wv**2, 2 * p.valve_damping / wv, 1])
    motor = control.tf([1 / p.motor_displacement_m3_per_rad], [1 / wh**2, 2 * p.motor_damping / wh, 1])
    return valve * motor * p.transmission_ratio * RPM_PER_RAD_S


def test_natural_frequencies_and_damping_match_the_paper():
    A, _ = state_space(P)
    eig = np.linalg.eigvals(A)
    osc = eig[np.abs(eig.imag) > 0]
    wn = np.abs(osc)
    zeta = -osc.real / wn
    found = sorted(zip(np.round(wn, 6), np.round(zeta, 9), strict=True))
    assert found[0][0] == pytest.approx(183.6, rel=1e-9) and found[0][1] == pytest.approx(0.12, rel=1e-9)
    assert found[-1][0] == pytest.approx(335.2, rel=1e-9) and found[-1][1] == pytest.approx(0.57, rel=1e-9)
    assert np.sum(np.abs(eig) < 1e-9) == 1  # the angle integrator


def test_dc_gain_is_ka_free_kq_over_dm_times_ratio():
    A, B = state_space(P)
    c = shaft_rpm_row(P)
    x_ss = np.linalg.lstsq(A[:4, :4], -B[:4, 0], rcond=None)[0]
    want = P.valve_flow_gain_m3_s_per_a / P.motor_displacement_m3_per_rad * 0.2 * 60 / (2 * math.pi)
    assert c[:4] @ x_ss == pytest.approx(want, rel=1e-12)
    assert P.shaft_rpm_per_a == pytest.approx(want, rel=1e-12)
    assert P.shaft_rpm_per_a == pytest.approx(250.0, rel=1e-5)  # the documented 1250 rpm motor at 1 A


def test_frequency_response_equals_the_paper_transfer_function():
    A, B = state_space(P)
    ss = control.ss(A, B[:, :1], shaft_rpm_row(P)[None, :], 0)
    w = np.logspace(0, 3.5, 50)
    ours = ss.frequency_response(w).complex.ravel()
    paper = paper_tf().frequency_response(w).complex.ravel()
    np.testing.assert_allclose(ours, paper, rtol=1e-9)


def test_load_torque_path_follows_eq_12_with_restored_sign():
    A, B = state_space(P)
    ss = control.ss(A, B[:, 1:], np.eye(5)[2:3], 0)   # load torque -> motor speed [rad/s]
    wh, zh = P.motor_natural_freq_rad_s, P.motor_damping
    kce_dm2 = 2 * zh / (wh * P.inertia_kg_m2)
    eq12 = -control.tf([kce_dm2 / (2 * zh * wh), kce_dm2], [1 / wh**2, 2 * zh / wh, 1])
    w = np.logspace(0, 3.5, 40)
    np.testing.assert_allclose(ss.frequency_response(w).complex.ravel(),
                               eq12.frequency_response(w).complex.ravel(), rtol=1e-9)


def test_zoh_step_matches_python_control_continuous_step_response():
    A, B = state_space(P)
    h = 0.001
    phi, gam = zoh(A, B[:, :1], h)
    x = np.zeros(5)
    c = shaft_rpm_row(P)
    ours = [0.0]
    for _ in range(300):
        x = phi @ x + gam[:, 0]
        ours.append(c @ x)
    t = np.arange(301) * h
    ref = control.step_response(paper_tf(), t).outputs
    scale = np.abs(ref).max()
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-6 * scale)


@pytest.mark.parametrize("field,value", [
    ("valve_damping", 0.0), ("motor_natural_freq_rad_s", -1.0), ("sensor_delay_s", -0.1),
    ("transmission_ratio", float("nan")), ("current_max_a", -0.5), ("shaft_rpm_max", 1e6),
    ("amplifier_gain_a_per_v", "0.3"),
])
def test_bad_parameters_name_field_and_value(field, value):
    with pytest.raises(ControllerError) as err:
        PlantParams(**{field: value})
    assert field in str(err.value) and repr(value) in str(err.value)
