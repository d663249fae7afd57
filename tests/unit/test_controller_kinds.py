"""The controller kinds through one interface: step responses against their documented behaviour, the
generic loop against the PID's lifted-matrix fast path, save/restore, configuration errors."""

import json
from importlib import resources

import numpy as np
import pytest

from vrsim.common import ControllerError
from vrsim.controller import (
    KINDS,
    ControllerConfig,
    PlantParams,
    build_controller,
    build_loop,
    simulate,
    step_metrics,
)
from vrsim.controller.calibration import valve_calibration
from vrsim.controller.factory import loop_info
from vrsim.controller.kinds.aog_pi import AogPiParams
from vrsim.controller.kinds.fuzzy_pid import _load_rules
from vrsim.controller.plant_loop import PlantLoop

P = PlantParams()
STEP_RPM = 100.0


def step_response(cfg, step_rpm=STEP_RPM, duration_s=10.0):
    """1 kHz metrics and metrics of the per-period mean speed (what is metered) of a step from rest."""
    res = simulate(P, cfg, step_rpm, duration_s)
    fine = step_metrics(res.t_s, res.shaft_rpm, step_rpm).row(0)
    mean_rpm = res.shaft_rev[:, 0] * 60.0 / 0.05
    period = step_metrics(np.arange(len(mean_rpm)) * 0.05, mean_rpm, step_rpm).row(0)
    return fine, period


def test_every_built_in_kind_is_registered():
    assert {"pid", "aog_pi", "ff_pi", "smith", "fuzzy_pid", "ideal", "python"} <= set(KINDS)
    for name, kind in KINDS.items():
        assert kind.summary and (kind.controller or kind.loop), name


def test_pid_step_is_the_papers_experiment():
    fine, period = step_response(ControllerConfig())
    assert fine["overshoot_pct"] == pytest.approx(24.2, abs=0.1)      # docs/model.md, vrsim paper
    assert fine["settling_2pct_s"] == pytest.approx(2.05, abs=0.01)
    assert period["overshoot_pct"] < 0.1


def test_aog_pi_step_creeps_up_without_overshoot_and_stops_inside_its_deadband():
    fine, period = step_response(ControllerConfig(kind="aog_pi"))
    assert period["overshoot_pct"] < 1.0
    assert 2.0 < fine["settling_5pct_s"] < 4.0              # slew-limited every 150 ms, slowed near target
    assert abs(fine["steady_state_error"]) <= 0.015 * STEP_RPM   # deadband 1.5 % of the target


def test_aog_pi_runs_every_pid_period_and_holds_in_between():
    ctrl = build_controller(ControllerConfig(kind="aog_pi"), P, n=1)
    target, reading = np.array([100.0]), np.array([0.0])
    currents = [ctrl.step(target, reading)[0] for _ in range(7)]
    # runs at periods 0, 3, 6 (150 ms at 50 ms); holds the output in between
    assert currents[0] == currents[1] == currents[2] < currents[3] == currents[4] == currents[5] < currents[6]
    # first run from rest: full error, change 1 x Kp 0.4 x 0.1 x authority (255 - 12.75 PWM counts), kept
    # at least at the 5 % minimum PWM; the next run adds the same change again
    change = 0.4 * 0.1 * (255.0 - 12.75)
    assert currents[0] == pytest.approx(12.75 / 255.0)
    assert currents[3] == pytest.approx((12.75 + change) / 255.0)
    assert ctrl.step(np.array([0.0]), reading)[0] == 0.0      # no target: valve closed


def test_ff_pi_reaches_the_target_within_a_few_periods():
    fine, period = step_response(ControllerConfig(kind="ff_pi"))
    assert fine["settling_2pct_s"] < 0.5
    assert period["overshoot_pct"] < 8.0     # the motor's own ringing after the current step
    assert abs(fine["steady_state_error"]) < 1e-6


def test_ff_pi_valve_cal_learns_the_static_curve():
    cal = valve_calibration(loop_info(P), points=6)
    np.testing.assert_allclose(cal.shaft_rpm, cal.current_a * P.shaft_rpm_per_a, rtol=1e-12, atol=1e-9)
    assert cal.current_for(np.array([125.0]))[0] == pytest.approx(125.0 / P.shaft_rpm_per_a, rel=1e-12)


def test_ff_pi_integral_removes_a_load_torque_the_feedforward_does_not_know():
    loop = build_loop(P, ControllerConfig(kind="ff_pi"))
    out = loop.run(np.full(200, STEP_RPM), load_torque_nm=20.0)
    assert out.shaft_rpm[-1, 0] == pytest.approx(STEP_RPM, rel=1e-4)


def test_smith_predictor_settles_fast_without_overshoot():
    fine, period = step_response(ControllerConfig(kind="smith"))
    assert fine["overshoot_pct"] < 1.0 and period["overshoot_pct"] < 1.0
    assert fine["settling_2pct_s"] < 0.6                  # the paper PID: 2.05 s


def test_mistuned_smith_predictor_is_corrected_by_its_pid():
    cfg = ControllerConfig(kind="smith", params={"model_gain_scale": 0.8, "model_delay_s": 0.09})
    fine, _ = step_response(cfg)
    assert abs(fine["steady_state_error"]) < 1e-3


def test_fuzzy_pid_settles_faster_than_the_papers_pid_it_starts_from():
    fine, period = step_response(ControllerConfig(kind="fuzzy_pid"))
    assert fine["settling_2pct_s"] < 1.6 and period["overshoot_pct"] < 1.0
    assert fine["overshoot_pct"] < 24.0


def test_fuzzy_rules_come_from_the_data_file():
    rules = _load_rules()
    assert rules.shape == (3, 7, 7)
    assert rules[0, 0, 0] == 3 and rules[0, 6, 6] == -3     # Kp: PB for e NB/ec NB, NB for e PB/ec PB
    assert rules[2, 4].tolist() == [0.0] * 7                 # Kd: ZO all along e = PS



def test_fuzzy_inference_equals_the_weighted_mean_over_all_49_rules():
    ctrl = build_controller(ControllerConfig(kind="fuzzy_pid"), P, n=6)
    p, rules = ctrl.params, _load_rules()
    error = np.array([-80.0, -7.5, 0.0, 3.3, 15.0, 200.0])
    change = np.array([10.0, -60.0, 0.0, 12.5, -20.0, 1.0])

    def mu(x):      # seven triangles at -3..3, the ends saturating
        x = np.clip(x, -3.0, 3.0)
        return np.maximum(0.0, 1.0 - np.abs(x[:, None] - np.arange(-3.0, 4.0)))

    strength = np.minimum(mu(3 * error / p.error_span_rpm)[:, :, None],
                          mu(3 * change / p.error_change_span_rpm)[:, None, :])
    delta = np.einsum("nij,gij->gn", strength, rules) / strength.sum(axis=(1, 2))
    g = ctrl.tuned_gains(error, change)
    base = ctrl.base
    np.testing.assert_allclose(g.kp, np.maximum(base.kp + p.dkp_span / 3 * delta[0], 0), rtol=1e-12)
    np.testing.assert_allclose(g.ki, np.maximum(base.ki + p.dki_span_per_s / 3 * delta[1], 0), rtol=1e-12)
    np.testing.assert_allclose(g.kd, np.maximum(base.kd + p.dkd_span_s / 3 * delta[2], 0), rtol=1e-12,
                               atol=1e-15)


def test_fuzzy_rules_file_errors_name_the_file_and_entry(tmp_path):
    shipped = resources.files("vrsim.controller").joinpath("data", "fuzzy_pid_rules.toml").read_text()
    bad = tmp_path / "rules.toml"
    bad.write_text(shipped.replace('"PB", "PB", "PM", "PM"', '"PB", "XL", "PM", "PM"', 1))
    with pytest.raises(ControllerError, match=r"rules.toml.*delta_kp.*'XL'"):
        build_controller(ControllerConfig(kind="fuzzy_pid", params={"rules_file": str(bad)}), P)


def test_ideal_meter_turns_exactly_at_the_target():
    loop = build_loop(P, ControllerConfig(kind="ideal"))
    targets = np.r_[np.full(5, 50.0), np.full(5, 500.0), np.full(5, -3.0)]
    out = loop.run(targets)
    np.testing.assert_array_equal(out.shaft_rpm[:, 0], np.clip(targets, 0, P.shaft_rpm_max))
    np.testing.assert_allclose(out.shaft_rev[:, 0], out.shaft_rpm[:, 0] * 0.05 / 60.0)
    assert loop.motor_angle_rad[0] == pytest.approx(out.shaft_rev.sum() * 2 * np.pi / 0.2)


@pytest.mark.parametrize("cfg", [
    ControllerConfig(),
    ControllerConfig(kind="PI", form="positional", gains="manual", kp=0.1, ki=5.0),
    ControllerConfig(kind="PID", gains="textbook", derivative_on_measurement=True),
    ControllerConfig(kind="PID", form="positional", gains="textbook", derivative_on_measurement=True),
    ControllerConfig(kind="P", gains="manual", kp=0.5),
])
def test_generic_loop_with_pid_equals_the_fast_path(cfg):
    rng = np.random.default_rng(7)
    targets = np.repeat(rng.uniform(-20.0, 260.0, size=(50, 3)), 30, axis=0)   # saturates both ways
    fast = build_loop(P, cfg, n=3)
    generic = build_loop(P, cfg, n=3, fast=False)
    assert isinstance(generic, PlantLoop) and not isinstance(fast, PlantLoop)
    a, b = fast.run(targets, load_torque_nm=5.0), generic.run(targets, load_torque_nm=5.0)
    for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_allclose(y, x, rtol=1e-9, atol=1e-9 * np.abs(x).max(), err_msg=name)
    np.testing.assert_allclose(generic.motor_angle_rad, fast.motor_angle_rad, rtol=1e-9)


def test_generic_fine_samples_equal_the_fast_paths():
    fast = simulate(P, ControllerConfig(kind="PI"), 120.0, 1.0)
    loop = build_loop(P, ControllerConfig(kind="PI"), fast=False, record_fine=True)
    fine = np.concatenate([loop.step_fine(120.0)[1][0] for _ in range(20)])
    np.testing.assert_allclose(fine, fast.shaft_rpm[0, 1:], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kind", ["PID", "aog_pi", "ff_pi", "smith", "fuzzy_pid", "ideal"])
def test_state_saved_mid_run_through_json_resumes_bitwise_identically(kind):
    cfg = ControllerConfig(kind=kind)
    targets = np.r_[np.full(40, 80.0), np.full(40, 150.0), np.full(40, 20.0)]
    targets = np.column_stack([targets, targets[::-1]])
    whole = build_loop(P, cfg, n=2, fast=False)
    first = whole.run(targets[:55])
    saved = json.loads(json.dumps(whole.state, default=lambda a: a.tolist()))
    rest = whole.run(targets[55:])
    resumed = build_loop(P, cfg, n=2, fast=False)
    resumed.set_state(saved)
    again = resumed.run(targets[55:])
    for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
        np.testing.assert_array_equal(getattr(again, name), getattr(rest, name), err_msg=name)
    assert np.any(first.shaft_rpm != 0)
    resumed.reset()
    assert resumed.step(np.zeros(2)).shaft_rpm.tolist() == [0.0, 0.0]


def test_fast_path_state_also_survives_json():
    loop = build_loop(P, ControllerConfig())
    loop.run(np.full(30, 90.0))
    saved = json.loads(json.dumps(loop.state.tolist()))
    rest = loop.run(np.full(30, 40.0))
    other = build_loop(P, ControllerConfig())
    other.set_state(saved)
    np.testing.assert_array_equal(other.run(np.full(30, 40.0)).shaft_rpm, rest.shaft_rpm)


def test_batch_of_generic_loops_equals_single_runs():
    targets = np.column_stack([np.full(80, 60.0), np.full(80, 140.0)])
    both = build_loop(P, ControllerConfig(kind="fuzzy_pid"), n=2).run(targets)
    for i in range(2):
        one = build_loop(P, ControllerConfig(kind="fuzzy_pid")).run(targets[:, i])
        np.testing.assert_allclose(both.shaft_rpm[:, i], one.shaft_rpm[:, 0], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kwargs,message", [
    ({"kind": "bang_bang"}, r"kind must be one of .*aog_pi.*got 'bang_bang'"),
    ({"kind": "aog_pi", "params": {"deadband_pct": -1.0}},
     r"aog_pi deadband_pct must be a number in \[0, 100\], got -1.0"),
    ({"kind": "aog_pi", "params": {"deadband": 1.0}}, r"aog_pi params: unknown key 'deadband'"),
    ({"kind": "aog_pi", "params": {"min_pwm_pct": 50.0, "max_pwm_pct": 40.0}}, r"max_pwm_pct.*40.0"),
    ({"kind": "ff_pi", "params": {"feedforward": "magic"}}, r"ff_pi feedforward must be one of.*'magic'"),
    ({"kind": "ff_pi", "params": {"cal_points": 2.5}}, r"ff_pi cal_points must be a whole number.*2.5"),
    ({"kind": "smith", "params": {"ki": "fast"}}, r"smith ki must be a number >= 0, got 'fast'"),
    ({"kind": "smith", "params": {"model_gain_scale": 0.0}}, r"smith model_gain_scale must be a number > 0"),
    ({"kind": "fuzzy_pid", "params": {"kp": 0.3}}, r"fuzzy_pid kp is only used with gains='manual'"),
    ({"kind": "smith", "gains": "textbook"}, r"controller gains is a key of kinds P, PI, PID.*'textbook'"),
    ({"kind": "PID", "params": {"kp": 1.0}}, r"controller params is for kinds other than P, PI, PID"),
    ({"kind": "PI", "file": "x.py"}, r"controller file is only for kind 'python'.*'x.py'"),
    ({"kind": "python", "class_name": "X"}, r"controller file is required with kind 'python'"),
])
def test_bad_configuration_names_kind_key_and_value(kwargs, message):
    with pytest.raises(ControllerError, match=message):
        ControllerConfig(**kwargs)


def test_params_dataclass_defaults_are_rate_controllers():
    p = AogPiParams()
    assert (p.kp_slider_pct, p.ki_slider_pct, p.deadband_pct, p.brake_point_pct, p.slow_adjust_pct) == \
        (40.0, 60.0, 1.5, 35.0, 60.0)
    assert (p.slew_rate_pwm_per_run, p.max_integral_pwm_per_run, p.min_pwm_pct, p.pid_period_s) == \
        (25.0, 25.0, 5.0, 0.15)
    assert AogPiParams.from_dict(p.to_dict()) == p


def test_from_table_renames_class_and_resolves_the_file(tmp_path):
    cfg = ControllerConfig.from_table({"kind": "python", "file": "ctl.py", "class": "C", "params": {"a": 1}},
                                      base_dir=str(tmp_path))
    assert cfg.file == str(tmp_path / "ctl.py") and cfg.class_name == "C" and cfg.params == {"a": 1}
    with pytest.raises(ControllerError, match="unknown key 'klass'"):
        ControllerConfig.from_table({"kind": "python", "klass": "C"})
    assert ControllerConfig.from_table({"kind": "PI", "gains": "textbook"}) == \
        ControllerConfig(kind="PI", gains="textbook")
