"""The closed loop: exact against python-control, batch = single runs, PID forms, limits, state."""

from dataclasses import replace

import control
import numpy as np
import pytest

from tests.unit.test_controller_plant import paper_tf
from vrsim.common import ControllerError
from vrsim.controller import (
    ClosedLoop,
    ControllerConfig,
    PidGains,
    PlantParams,
    build_loop,
    simulate,
    unlimited,
)

P = PlantParams()


def test_fine_output_matches_python_control_for_the_loops_own_currents():
    """The 1 ms shaft speed of a saturating PID loop equals python-control's continuous response to the
    same piecewise-constant currents (superposed exact step responses) to 1e-6 relative."""
    targets = np.r_[np.full(20, 150.0), np.full(20, 40.0), np.full(20, 190.0)]
    res = simulate(P, ControllerConfig(gains="textbook"), targets[:, None], 3.0)
    currents = res.current_a[:, 0]
    assert currents.max() == P.current_max_a and currents.min() == P.current_min_a  # limits exercised
    t = res.t_s
    step = control.step_response(paper_tf(), t).outputs
    ref = np.zeros_like(t)
    for k, di in enumerate(np.diff(np.r_[0.0, currents])):
        start = k * 50
        ref[start:] += di * step[:len(t) - start]
    np.testing.assert_allclose(res.shaft_rpm[0], ref, rtol=0, atol=1e-6 * np.abs(ref).max())


def test_shaft_rev_is_the_integral_of_the_speed():
    res = simulate(P, ControllerConfig(), 120.0, 2.0)
    fine = res.shaft_rpm[0] / 60.0
    per_tick = np.array([np.trapezoid(fine[k * 50:(k + 1) * 50 + 1], dx=0.001) for k in range(40)])
    np.testing.assert_allclose(res.shaft_rev[:, 0], per_tick, rtol=0, atol=2e-4 * per_tick.max())
    loop = build_loop(P, ControllerConfig())
    revs = sum(loop.step(120.0).shaft_rev[0] for _ in range(40))
    assert revs == pytest.approx(loop.motor_angle_rad[0] * 0.2 / (2 * np.pi), rel=1e-12)


def test_batch_equals_single_runs():
    plants = [P, replace(P, sensor_delay_s=0.02), replace(P, motor_damping=0.3, current_max_a=0.8)]
    gains = [PidGains(0.573, 2.1, 0.0), PidGains(0.3), PidGains(0.5, 1.0, 0.01)]
    rng = np.random.default_rng(3)
    targets = rng.uniform(0, 200, size=(60, 3))
    batch = simulate(plants, gains, targets, 3.0)
    for i in range(3):
        single = simulate(plants[i], gains[i], targets[:, i:i + 1], 3.0)
        np.testing.assert_allclose(batch.shaft_rpm[i], single.shaft_rpm[0], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(batch.current_a[:, i], single.current_a[:, 0], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("form", ["incremental", "positional"])
def test_scalar_fast_path_equals_array_path_and_batch(form):
    cfg = ControllerConfig(form=form, gains="manual", kind="PI", kp=0.1, ki=5.0)  # saturates both ways
    weak = replace(P, current_max_a=0.8, shaft_rpm_max=195.0)
    a, b, c = build_loop(weak, cfg), build_loop(weak, cfg), build_loop(weak, cfg, n=2)
    saved, currents = None, []
    for k in range(120):
        target = 195.0 if (k // 30) % 2 == 0 else 5.0
        oa, ob, oc = a.step(target), b.step(np.array([target])), c.step(np.array([target, target]))
        for x, y in ((oa, ob), (oa, oc)):
            np.testing.assert_allclose(x.shaft_rpm[0], y.shaft_rpm[0], rtol=1e-12, atol=1e-10)
            np.testing.assert_allclose(x.current_a[0], y.current_a[0], rtol=1e-12, atol=1e-13)
        currents.append(oa.current_a[0])
        if k == 40:
            saved = a.state
    assert min(currents) == weak.current_min_a and max(currents) == weak.current_max_a
    a.set_state(saved)      # the scalar path's cached PID term is rebuilt from the state
    b.set_state(saved)
    for _ in range(20):
        np.testing.assert_allclose(a.step(150.0).current_a, b.step(np.array([150.0])).current_a, rtol=1e-12)


@pytest.mark.parametrize("dom", [False, True])
def test_incremental_equals_positional_without_saturation(dom):
    lin = unlimited(P)
    runs = [simulate(lin, ControllerConfig(form=f, derivative_on_measurement=dom, gains="textbook"),
                     100.0, 5.0) for f in ("incremental", "positional")]
    np.testing.assert_allclose(runs[0].shaft_rpm, runs[1].shaft_rpm, rtol=1e-9, atol=1e-8)


def test_forms_differ_only_through_anti_windup_when_saturated():
    weak = replace(P, current_max_a=0.8, shaft_rpm_max=195.0)   # 195 rpm needs 0.78 A: long saturation
    cfg = dict(gains="manual", kind="PI", kp=0.1, ki=5.0)     # integral-heavy: overshoots into the limit
    runs = {f: simulate(weak, ControllerConfig(form=f, **cfg), 195.0, 8.0)
            for f in ("incremental", "positional")}
    for r in runs.values():
        assert r.current_a.min() >= weak.current_min_a and r.current_a.max() == weak.current_max_a
        assert abs(r.shaft_rpm[0, -1] - 195.0) < 0.5       # both reach the setpoint: no windup lock
    assert not np.allclose(runs["incremental"].current_a, runs["positional"].current_a)


def test_derivative_on_measurement_removes_the_setpoint_kick():
    gains = PidGains(0.3, 0.5, 0.02)
    kick = [simulate(unlimited(P), gains, 100.0, 0.1, derivative_on_measurement=dom).current_a[0, 0]
            for dom in (False, True)]
    ks, ka = P.sensor_gain_v_per_rpm, P.amplifier_gain_a_per_v
    assert kick[0] == pytest.approx(ka * ks * 100 * (0.3 + 0.5 * 0.05 + 0.02 / 0.05))
    assert kick[1] == pytest.approx(ka * ks * 100 * (0.3 + 0.5 * 0.05))


def test_target_is_clipped_to_the_shaft_limit_and_state_round_trips():
    loop = build_loop(P, ControllerConfig())
    for _ in range(200):
        out = loop.step(1e4)
    assert out.shaft_rpm[0] == pytest.approx(P.shaft_rpm_max, rel=1e-3)
    saved = loop.state
    a = [loop.step(50.0).shaft_rpm[0] for _ in range(10)]
    loop.set_state(saved)
    assert [loop.step(50.0).shaft_rpm[0] for _ in range(10)] == a
    loop.reset()
    assert np.all(loop.state == 0) and loop.step(0.0).shaft_rpm[0] == 0.0


def test_measured_rpm_is_the_delayed_shaft_speed():
    loop = build_loop(P, ControllerConfig(), n=1)
    outs = [loop.step(100.0) for _ in range(30)]
    # d = 3 periods, offset 0.0458 s: the reading at tick k is the speed at 50 k - 104.2 ms
    fine = simulate(P, ControllerConfig(), 100.0, 1.5)
    k = 20
    t_read = k * 0.05 - P.sensor_delay_s
    assert outs[k].measured_rpm[0] == pytest.approx(np.interp(t_read, fine.t_s, fine.shaft_rpm[0]), rel=1e-3)


def test_bad_inputs_raise_controller_error():
    loop = build_loop(P, ControllerConfig())
    with pytest.raises(ControllerError, match="target_shaft_rpm"):
        loop.step(float("nan"))
    with pytest.raises(ControllerError, match="n must be"):
        build_loop(P, ControllerConfig(), n=0)
    with pytest.raises(ControllerError, match="whole multiple"):
        build_loop(P, ControllerConfig(), control_period_s=0.05, plant_step_s=0.003)
    with pytest.raises(ControllerError, match="plants must be one value or 2"):
        ClosedLoop([P, P, P], PidGains(0.5), n=2)


def test_run_equals_step_by_step():
    targets = np.r_[np.full(30, 150.0), np.full(30, 20.0), np.full(30, 250.0)]
    a, b = build_loop(P, ControllerConfig()), build_loop(P, ControllerConfig())
    rec = a.run(targets)
    outs = [b.step(float(t)) for t in targets]
    for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
        np.testing.assert_array_equal(getattr(rec, name)[:, 0], [getattr(o, name)[0] for o in outs])
    two = build_loop(P, ControllerConfig(), n=2).run(np.column_stack([targets, targets / 2]))
    np.testing.assert_allclose(two.shaft_rpm[:, 0], rec.shaft_rpm[:, 0], rtol=1e-12, atol=1e-10)
    with pytest.raises(ControllerError, match="targets_rpm"):
        a.run(np.zeros((5, 3)))


@pytest.mark.parametrize("form", ["incremental", "positional"])
@pytest.mark.parametrize("dom", [False, True])
@pytest.mark.parametrize("shared_target", [False, True])
def test_run_of_loops_with_their_own_gains_equals_each_loop_alone(form, dom, shared_target):
    """`run` of n loops with gains per loop (the variants' fast path: the PID output as weights of four
    shared basis outputs) equals each loop run alone to 1e-9 relative, saturating both ways, with a
    load torque, on one target row for all (a broadcast view) or a row per loop, and carries on with
    `step` after it."""
    weak = replace(P, current_max_a=0.8, shaft_rpm_max=195.0)
    gains = [PidGains(0.1, 5.0, 0.0), PidGains(0.573, 2.1, 0.004), PidGains(1.2, 0.5, 0.01)]
    targets = np.r_[np.full(40, 195.0), np.full(40, 5.0), np.full(40, 120.0)]
    rows = (np.broadcast_to(targets[:, None], (120, 3)) if shared_target
            else np.column_stack([targets, targets / 2, targets * 0.8]))
    batch = ClosedLoop(weak, gains, form=form, derivative_on_measurement=dom, n=3)
    got = batch.run(rows, 0.02)
    after = batch.step(rows[-1], 0.02)
    for i in range(3):
        one = ClosedLoop(weak, gains[i], form=form, derivative_on_measurement=dom)
        want = one.run(np.ascontiguousarray(rows[:, i]), 0.02)
        for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
            np.testing.assert_allclose(getattr(got, name)[:, i], getattr(want, name)[:, 0], rtol=1e-9,
                                       atol=1e-12, err_msg=name)
        np.testing.assert_allclose(after.shaft_rpm[i], one.step(rows[-1, i], 0.02).shaft_rpm[0], rtol=1e-9)
    assert got.current_a.max() == weak.current_max_a and got.current_a.min() == weak.current_min_a


def test_load_torque_is_rejected_by_integral_action_at_the_predicted_current():
    loop = build_loop(P, ControllerConfig(kind="PI"))
    for _ in range(300):
        out = loop.step(100.0, load_torque_nm=20.0)
    assert out.shaft_rpm[0] == pytest.approx(100.0, rel=1e-6)
    # the valve must supply the motor-speed droop of eq. 12: Kce/Dm^2 * T_L [rad/s] more
    droop_rpm = P.load_droop_rad_s_per_nm * 20.0 * P.transmission_ratio * 60 / (2 * np.pi)
    assert out.current_a[0] == pytest.approx((100.0 + droop_rpm) / P.shaft_rpm_per_a, rel=1e-6)


@pytest.mark.parametrize("form", ["incremental", "positional"])
@pytest.mark.parametrize("shared_gains", [False, True])
def test_loops_run_in_calls_split_anywhere_give_the_one_calls_numbers_bit_for_bit(form, shared_gains):
    """n loops of one plant (the shared lifted path: a drive per section, sweeps' variants) run in
    calls split at any ticks give the one call's outputs bit for bit, saturating both ways; a loop
    restored from `state` (as after JSON) carries on equal to rounding."""
    weak = replace(P, current_max_a=0.8, shaft_rpm_max=195.0)
    gains = [PidGains(1.2, 0.5, 0.01)] * 3 if shared_gains else \
        [PidGains(0.1, 5.0, 0.0), PidGains(0.573, 2.1, 0.004), PidGains(1.2, 0.5, 0.01)]
    targets = np.r_[np.full(40, 195.0), np.full(40, 5.0), np.full(40, 120.0)]
    rows = np.column_stack([targets, targets / 2, targets * 0.8])
    whole = ClosedLoop(weak, gains, form=form, n=3).run(rows, 0.02)
    loop = ClosedLoop(weak, gains, form=form, n=3)
    parts = [loop.run(rows[lo:hi], 0.02) for lo, hi in ((0, 1), (1, 37), (37, 37), (37, 80), (80, 81),
                                                          (81, 120))]
    for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]),
                                      getattr(whole, name), err_msg=name)
    assert whole.current_a.max() == weak.current_max_a and whole.current_a.min() == weak.current_min_a
    first = ClosedLoop(weak, gains, form=form, n=3)
    first.run(rows[:37], 0.02)
    restored = ClosedLoop(weak, gains, form=form, n=3)
    restored.set_state(np.asarray(first.state).tolist())
    np.testing.assert_allclose(restored.run(rows[37:], 0.02).shaft_rpm, whole.shaft_rpm[37:], rtol=1e-12)


@pytest.mark.parametrize("form", ["incremental", "positional"])
@pytest.mark.parametrize("load", [0.0, 0.02])
def test_one_loops_run_equals_step_by_step_bit_for_bit_saturated_and_loaded(form, load):
    cfg = ControllerConfig(form=form, gains="manual", kind="PI", kp=0.1, ki=5.0)  # saturates both ways
    weak = replace(P, current_max_a=0.8, shaft_rpm_max=195.0)
    a, b = build_loop(weak, cfg), build_loop(weak, cfg)
    targets = np.r_[np.full(40, 400.0), np.full(40, -5.0), np.full(40, 120.0)]   # clipped both ways
    rec = a.run(targets, load)
    outs = [b.step(float(t), load) for t in targets]
    for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
        np.testing.assert_array_equal(getattr(rec, name)[:, 0], [getattr(o, name)[0] for o in outs])
    np.testing.assert_array_equal(a.state, b.state)
    limits = {weak.current_min_a, weak.current_max_a}
    assert {float(rec.current_a.min()), float(rec.current_a.max())} == limits
    with pytest.raises(ControllerError, match="a number"):
        a.run(np.r_[150.0, np.nan])
    b.step(150.0)
    np.testing.assert_array_equal(a.state, b.state)   # the ticks before the bad one are stepped
