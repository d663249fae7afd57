"""Step metrics against control.step_info on the same responses."""

import control
import numpy as np
import pytest

from vrsim.controller import PidGains, PlantParams, simulate, step_metrics, unlimited


@pytest.fixture(scope="module")
def responses():
    gains = [PidGains(0.573), PidGains(0.573, 2.118, 3e-5), PidGains(0.43, 1.66), PidGains(0.2, 0.8)]
    res = simulate(unlimited(PlantParams()), gains, 100.0, 12.0)
    return res.t_s, res.shaft_rpm


def test_metrics_agree_with_step_info(responses):
    t, y = responses
    m = step_metrics(t, y, 100.0)
    for i in range(y.shape[0]):
        ref2 = control.step_info(y[i], t, SettlingTimeThreshold=0.02)
        ref5 = control.step_info(y[i], t, SettlingTimeThreshold=0.05)
        assert m.overshoot_pct[i] == pytest.approx(ref2["Overshoot"], rel=1e-12, abs=1e-9)
        assert m.rise_s[i] == pytest.approx(ref2["RiseTime"], rel=1e-12)
        assert m.settling_2pct_s[i] == pytest.approx(ref2["SettlingTime"], rel=1e-12)
        assert m.settling_5pct_s[i] == pytest.approx(ref5["SettlingTime"], rel=1e-12)


def test_integral_criteria_and_steady_state_error():
    t = np.linspace(0, 10, 10001)
    y = 1 - np.exp(-t)
    m = step_metrics(t, y, 1.0)
    assert m.iae[0] == pytest.approx(1 - np.exp(-10), rel=1e-6)
    assert m.itae[0] == pytest.approx(1 - 11 * np.exp(-10), rel=1e-6)
    assert m.steady_state_error[0] == pytest.approx(np.exp(-10))
    assert m.overshoot_pct[0] == 0.0
