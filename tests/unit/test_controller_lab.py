"""The controller lab's wiring without SUMO: scenario [controller] tables of every kind, the look-ahead
and its auto-tune, one loop on floats equal to n loops on arrays, compare's specs and its best-of
marking, and `vrsim controller analyze`'s report and pictures."""

from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest

from tests.conftest import ROOT
from vrsim.common import ScenarioError
from vrsim.controller import ControllerConfig, PlantParams, build_controller, build_loop
from vrsim.controller.analysis import analyze_loop
from vrsim.controller.response import response_time
from vrsim.services.outputs.loop_analysis import text, write_pictures
from vrsim.services.sim import scenario
from vrsim.services.sim.analyze import analyze_controller
from vrsim.services.sim.compare import BETTER, _builtin_specs, best_rows, resolve_spec
from vrsim.services.sim.core import plant_for
from vrsim.services.sim.look_ahead import TUNE_WINDOW_S, LookAheadTuner, initial_look_ahead_s, known_delay_s
from vrsim.services.sim.scenario import with_changes

P = PlantParams()
T = 0.05
BASE = """
name = "lab"
[field]
rectangle = { width_m = 72.0, length_m = 150.0, lat = 52.0, lon = 10.0 }
[map]
synthetic = "zones"
[implement]
delivery_delay_s = 0.8
"""
KIND_TABLES = {
    "PID": 'kind = "PID"\ngains = "textbook"',
    "pid": 'kind = "pid"',
    "aog_pi": 'kind = "aog_pi"\nparams = { deadband_pct = 2.0, pid_period_s = 0.1 }',
    "ff_pi": 'kind = "ff_pi"\nparams = { feedforward = "model", kp = 0.3 }',
    "smith": 'kind = "smith"\nparams = { kp = 0.12, model_delay_s = 0.1 }',
    "fuzzy_pid": 'kind = "fuzzy_pid"\nparams = { dkp_span = 0.3 }',
    "ideal": 'kind = "ideal"',
    "python": 'kind = "python"\nfile = "my_controller.py"\nclass = "MyController"\n'
              'params = { kp_a_per_rpm = 0.002 }',
}


def write_scenario(folder, controller_table: str, name="lab.toml") -> str:
    path = os.path.join(folder, name)
    with open(path, "w") as fh:
        fh.write(BASE + "[controller]\n" + controller_table + "\n")
    return path


@pytest.fixture
def folder(tmp_path):
    shutil.copy(os.path.join(ROOT, "scenarios", "my_controller.py"), tmp_path)
    return str(tmp_path)


# ------------------------------------------------------------------------- scenario tables
@pytest.mark.parametrize("kind", list(KIND_TABLES))
def test_every_kind_loads_from_a_scenario_and_builds_its_loop(folder, kind):
    sc = scenario.load(write_scenario(folder, KIND_TABLES[kind]))
    assert sc.controller.kind == kind
    loop = build_loop(plant_for(sc), sc.controller)
    out = loop.run(np.full(40, 80.0))
    assert out.shaft_rpm[-1, 0] > 40.0
    if kind == "python":   # `class` is class_name, `file` is taken from the scenario's folder
        assert sc.controller.class_name == "MyController"
        assert sc.controller.file == os.path.join(folder, "my_controller.py")
        assert sc.controller.params == {"kp_a_per_rpm": 0.002}


@pytest.mark.parametrize("table, message", [
    ('kind = "python"\nfile = "nowhere.py"\nclass = "X"', "[controller] file 'nowhere.py': no such file"),
    ('kind = "python"\nfile = "my_controller.py"\nclass_name = "X"', "[controller] unknown key 'class_name'"),
    ('kind = "smith"\nclas = "X"', "[controller] unknown key 'clas'"),
    ('kind = "aog_pi"\nparams = { slew_rate_pwm_per_run = -2.0 }',
     "aog_pi slew_rate_pwm_per_run must be a number"),
    ('kind = "smith"\nlook_ahead_s = "soon"',
     "look_ahead_s must be \"auto\" or a number in [0, 30] s, got 'soon'"),
    ('kind = "PID"\nlook_ahead_s = 45.0', "look_ahead_s must be \"auto\" or a number in [0, 30] s, got 45.0"),
    ('kind = "PID"\nlook_ahead_tune = 1.5', "look_ahead_tune must be a number in [0, 1], got 1.5"),
    ('kind = "ff_pi"\ngains = "paper"', "controller gains is a key of kinds P, PI, PID"),
])
def test_bad_controller_table_names_file_table_key_and_value(folder, table, message):
    path = write_scenario(folder, table)
    with pytest.raises(ScenarioError) as err:
        scenario.load(path)
    assert str(err.value).startswith(f"{path}: [controller]") and message in str(err.value)


def test_a_user_class_that_does_not_load_is_a_scenario_error_at_build(folder):
    with open(os.path.join(folder, "broken.py"), "w") as fh:
        fh.write("import numpy\n\nclass Broken:\n    pass\n")
    sc = scenario.load(write_scenario(folder, 'kind = "python"\nfile = "broken.py"\nclass = "Broken"'))
    from vrsim.services.sim.core import ControlCore
    from vrsim.services.sim.world import build_world

    world = build_world(sc)
    with pytest.raises(ScenarioError, match=r"lab.toml: \[controller\] controller file .*broken.py: class "
                                            r"Broken has no method step\(\)"):
        ControlCore(world.grid, sc, world.field.polygon, world.path)


def test_changing_the_kind_starts_from_its_defaults_and_keeps_the_look_ahead(folder):
    sc = scenario.load(write_scenario(folder, 'kind = "PID"\ngains = "textbook"\nlook_ahead_s = "auto"'))
    smith = with_changes(sc, controller={"kind": "smith", "params": {"kp": 0.2}}).controller
    assert (smith.kind, smith.gains, smith.params, smith.look_ahead_s) == ("smith", None, {"kp": 0.2}, "auto")
    pi = with_changes(sc, controller={"kind": "PI"}).controller
    assert (pi.gains, pi.look_ahead_s) == ("textbook", "auto")   # P, PI, PID share their keys
    user = with_changes(sc, controller={"kind": "python", "file": "my_controller.py",
                                        "class": "MyController"})
    assert user.controller.file == os.path.join(folder, "my_controller.py")


# ------------------------------------------------------------------------------- look-ahead
def test_look_ahead_default_number_and_auto(folder):
    sc = scenario.load(write_scenario(folder, 'kind = "smith"'))
    plant = plant_for(sc)
    assert initial_look_ahead_s(sc, plant) == 0.8                      # unset: the delivery delay
    fixed = with_changes(sc, controller={"look_ahead_s": 1.25})
    assert initial_look_ahead_s(fixed, plant) == 1.25
    auto = with_changes(sc, controller={"look_ahead_s": "auto"})
    lag = response_time(plant, auto.controller).look_ahead_s
    assert known_delay_s(sc) == pytest.approx(0.8 + 0.1 + 0.05)          # + RTK latency + half a 10 Hz fix
    assert initial_look_ahead_s(auto, plant) == pytest.approx(0.95 + lag)
    assert 0.02 < lag < 0.2


def lagged_step(before, after, lag_s, n):
    """Per-period mean speeds of a first-order lag with time constant `lag_s`: its centroid is lag_s."""
    k = np.arange(n)
    a = math.exp(-T / lag_s)
    # mean over period k of 1 - exp(-t/tau): exact, so the measured lag is exactly lag_s (plus rounding)
    mean = 1.0 - lag_s / T * (a ** k) * (1.0 - a)
    return before + (after - before) * mean


def tune_inputs(step_at=20, n=200, before=60.0, after=90.0, lag_s=0.3):
    rate = np.where(np.arange(n) < step_at, 150.0, 225.0)
    target = np.where(np.arange(n) < step_at, before, after)
    metered = np.full(n, before)
    metered[step_at:] = lagged_step(before, after, lag_s, n - step_at)
    return rate, target, np.full(n, 12.0), np.ones(n, bool), metered


def test_tuner_moves_the_look_ahead_by_its_gain_times_the_measured_lateness():
    rate, target, width, on, metered = tune_inputs(lag_s=0.3)
    tuner = LookAheadTuner(0.8, known_delay_s=0.95, gain=0.5, control_period_s=T)
    end = tuner.plan(rate, target, width, on)
    assert end == 20 + round(TUNE_WINDOW_S / T)                       # the tick after the window
    tuner.observe(rate[:end], target[:end], width[:end], on[:end], metered[:end])
    measured_lag_s = 0.3 * (1.0 - math.exp(-TUNE_WINDOW_S / 0.3))      # the centroid within the window
    late_s = 0.95 + measured_lag_s - 0.8
    assert tuner.look_ahead_s == pytest.approx(0.8 + 0.5 * late_s, abs=1e-12)
    assert tuner.updates == 1 and tuner.plan(rate[end:], target[end:], width[end:], on[end:]) is None


def test_tuner_gives_the_same_look_ahead_whatever_the_batches():
    rate, target, width, on, metered = tune_inputs()
    whole = LookAheadTuner(0.8, 0.95, 1.0, T)
    end = whole.plan(rate, target, width, on)
    whole.observe(rate[:end], target[:end], width[:end], on[:end], metered[:end])
    pieces = LookAheadTuner(0.8, 0.95, 1.0, T)
    start = 0
    for stop in (7, 20, 21, 50, 77, end):
        got = pieces.plan(rate[start:stop], target[start:stop], width[start:stop], on[start:stop])
        assert got is None or start + got == end
        pieces.observe(rate[start:stop], target[start:stop], width[start:stop], on[start:stop],
                       metered[start:stop])
        saved = pieces.state()
        pieces = LookAheadTuner(0.8, 0.95, 1.0, T)
        pieces.set_state(saved)
        start = stop
    assert pieces.look_ahead_s == whole.look_ahead_s and pieces.updates == 1


@pytest.mark.parametrize("spoil", ["second step", "width change", "implement off", "no target change"])
def test_tuner_drops_a_step_that_is_not_clean(spoil):
    rate, target, width, on, metered = tune_inputs()
    if spoil == "second step":
        rate[40:] = 120.0
    elif spoil == "width change":
        width[30:] = 6.0
    elif spoil == "implement off":
        on[50] = False
    else:
        target[:] = 60.0
    tuner = LookAheadTuner(0.8, 0.95, 1.0, T)
    end = tuner.plan(rate, target, width, on)
    tuner.observe(rate[:end], target[:end], width[:end], on[:end], metered[:end]) if end else \
        tuner.observe(rate, target, width, on, metered)
    assert tuner.look_ahead_s == 0.8 and tuner.updates == 0


# ------------------------------------------------------------------- one loop on floats
@pytest.mark.parametrize("cfg", [
    ControllerConfig(), ControllerConfig(kind="PI", form="positional", gains="manual", kp=0.1, ki=5.0),
    ControllerConfig(kind="aog_pi"), ControllerConfig(kind="ff_pi"),
    ControllerConfig(kind="ff_pi", params={"feedforward": "model"}), ControllerConfig(kind="smith"),
    ControllerConfig(kind="smith", params={"form": "positional", "kd": 0.001, "model_gain_scale": 1.2}),
    ControllerConfig(kind="fuzzy_pid"),
])
def test_one_loop_on_floats_equals_n_loops_on_arrays(cfg):
    rng = np.random.default_rng(11)
    targets = np.repeat(rng.uniform(-20.0, 260.0, size=(40, 2)), 25, axis=0)
    targets[500:540] = 0.0
    both = build_loop(P, cfg, n=2, fast=False).run(targets, load_torque_nm=3.0)
    for i in range(2):
        one = build_loop(P, cfg, n=1, fast=False)
        assert hasattr(one.controller, "step_one")
        got = one.run(targets[:, i], load_torque_nm=3.0)
        for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
            want = getattr(both, name)[:, i]
            np.testing.assert_allclose(getattr(got, name)[:, 0], want, rtol=1e-12,
                                       atol=1e-12 * np.abs(want).max(), err_msg=name)


def test_fuzzy_gains_on_floats_equal_those_on_arrays():
    ctrl = build_controller(ControllerConfig(kind="fuzzy_pid"), P, n=1)
    errors, changes = np.array([-80.0, -7.5, 0.0, 3.3, 15.0]), np.array([10.0, -60.0, 0.0, 12.5, -1.0])
    arrays = ctrl.tuned_gains(errors, changes)
    for i in range(len(errors)):
        g = ctrl.tuned_gains(float(errors[i]), float(changes[i]))
        assert (g.kp, g.ki, g.kd) == pytest.approx((arrays.kp[i], arrays.ki[i], arrays.kd[i]), rel=1e-14)


# ----------------------------------------------------------------------------------- compare
def test_compare_specs_kinds_and_files(folder):
    sc = scenario.load(write_scenario(folder, 'kind = "PID"\ngains = "textbook"\nlook_ahead_s = 1.1'))
    specs = _builtin_specs()
    assert specs[0] == "pid" and sorted(specs) == ["aog_pi", "ff_pi", "fuzzy_pid", "ideal", "pid", "smith"]
    pid = resolve_spec("pid", sc)
    assert (pid.config.kind, pid.config.gains, pid.config.look_ahead_s) == ("pid", "paper", 1.1)
    assert resolve_spec("smith", sc, look_ahead="auto").config.look_ahead_s == "auto"
    sub = os.path.join(folder, "specs")
    os.makedirs(sub)
    shutil.copy(os.path.join(folder, "my_controller.py"), sub)
    spec_file = os.path.join(sub, "mine.toml")
    with open(spec_file, "w") as fh:
        fh.write('[controller]\nkind = "python"\nfile = "my_controller.py"\nclass = "MyController"\n'
                 'look_ahead_tune = 0.2\n')
    mine = resolve_spec(spec_file, sc)
    assert mine.label == spec_file and mine.config.file == os.path.join(sub, "my_controller.py")
    assert (mine.config.look_ahead_s, mine.config.look_ahead_tune) == (1.1, 0.2)


@pytest.mark.parametrize("spec, message", [
    ("bang_bang", "controller spec 'bang_bang': neither a kind"),
    ("python", "needs a TOML file with file and class"),
])
def test_bad_compare_spec_is_a_scenario_error(folder, spec, message):
    sc = scenario.load(write_scenario(folder, 'kind = "PID"'))
    with pytest.raises(ScenarioError, match=message):
        resolve_spec(spec, sc)


def test_bad_compare_spec_file_names_it(folder):
    sc = scenario.load(write_scenario(folder, 'kind = "PID"'))
    path = os.path.join(folder, "nocontroller.toml")
    with open(path, "w") as fh:
        fh.write("[plant]\n")
    with pytest.raises(ScenarioError, match=f"{path}: needs a \\[controller\\] table"):
        resolve_spec(path, sc)
    with open(path, "w") as fh:
        fh.write('[controller]\nkind = "smith"\nparams = { kp = -1.0 }\n')
    with pytest.raises(ScenarioError, match=f"{path}: \\[controller\\] controller smith kp must be"):
        resolve_spec(path, sc)


def test_best_of_each_column_by_its_direction_ties_and_nulls():
    keys = list(BETTER)
    runs = [{k: 1.0 for k in keys}, {k: 2.0 for k in keys}, {k: -0.5 for k in keys}]
    runs[1]["transition_distance_m_mean"] = None
    runs[0]["mae_kg_ha"] = runs[2]["mae_kg_ha"] = 0.1234
    runs[2]["mae_kg_ha"] = 0.12341
    best = best_rows(runs, decimals=3)
    assert best["within_10pct_area_pct"] == {1}              # highest
    assert best["mass_balance_pct"] == {2}                   # closest to zero
    assert best["rmse_kg_ha"] == {2}                         # lowest
    assert best["mae_kg_ha"] == {0, 2}                       # equal to three decimals
    assert best_rows(runs)["mae_kg_ha"] == {0}
    assert best["transition_distance_m_mean"] == {2}


# ----------------------------------------------------------------------------------- analyze
def test_analyze_report_of_a_linear_and_a_nonlinear_controller(folder, tmp_path):
    sc = scenario.load(write_scenario(folder, 'kind = "smith"\nlook_ahead_s = "auto"'))
    report = analyze_controller(sc)
    direct = analyze_loop(plant_for(sc), sc.controller, T)
    assert report.loop.gain_margin == direct.gain_margin
    assert report.loop.crossover_rad_s == direct.crossover_rad_s
    la = report.look_ahead
    assert la["auto_s"] == pytest.approx(la["delivery_delay_s"] + la["fix_age_s"] + la["mean_lag_s"])
    assert la["used_s"] == la["auto_s"]
    out = text(report)
    assert f"{direct.gain_margin:.3f}" in out and f"{direct.phase_margin_deg:.1f} deg" in out
    assert f"{la['auto_s']:.3f} s" in out
    paths = write_pictures(report, str(tmp_path / "pics"))
    assert [os.path.basename(p) for p in paths] == ["bode.png", "step.png"]
    for p in paths:
        with open(p, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    nonlinear = analyze_controller(with_changes(sc, controller={"kind": "aog_pi"}))
    assert nonlinear.loop is None and "not linear" in nonlinear.no_loop_reason
    assert nonlinear.to_dict()["loop"] is None and nonlinear.response.look_ahead_s > 0.5
    assert [os.path.basename(p) for p in write_pictures(nonlinear, str(tmp_path / "nl"))] == ["step.png"]
