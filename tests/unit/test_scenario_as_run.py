"""The scenario as run (`services.sim.as_run`): every kind's default resolved once, the same loop bit for
bit; a scenario written as TOML (`scenario_toml.to_toml`) reads back to itself; the public table checks."""

import dataclasses
import os

import numpy as np
import pytest

from vrsim.common import ScenarioError
from vrsim.controller import build_loop, paper_gains
from vrsim.services.sim.as_run import as_run
from vrsim.services.sim.core import plant_for
from vrsim.services.sim.look_ahead import initial_look_ahead_s
from vrsim.services.sim.scenario import load, parse, with_changes
from vrsim.services.sim.scenario_toml import to_toml
from vrsim.services.sim.tables import no_unknown, typed
from vrsim.vehicle import GnssConfig, SpeedSensorConfig
from vrsim.vehicle.gnss import CLASSES as GNSS_CLASSES
from vrsim.vehicle.speed_sensor import CLASSES as SPEED_CLASSES

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# Targets that step up, saturate the shaft's range and fall back: the loops' limits and memory at work.
TARGETS_RPM = np.concatenate([np.full(40, 60.0), np.full(40, 140.0), np.full(30, 400.0), np.full(40, 20.0)])


def loop_output(scenario):
    timing = scenario.timing
    loop = build_loop(plant_for(scenario), scenario.controller, control_period_s=timing.control_period_s,
                      plant_step_s=timing.plant_step_s, n=1)
    out = loop.run(TARGETS_RPM)
    return out.shaft_rpm, out.current_a


def test_default_scenario_shows_the_paper_gains_the_rtk_grade_and_the_radar():
    sc = as_run(load(None))
    c = sc.controller
    assert c.gains == "manual" and (c.kp, c.ki, c.kd) == dataclasses.astuple(paper_gains("PID"))
    assert c.look_ahead_s == sc.implement.delivery_delay_s
    assert (sc.gnss.sigma_m, sc.gnss.tau_s) == GNSS_CLASSES["rtk"]
    assert (sc.speed_sensor.noise_pct, sc.speed_sensor.bias_pct) == SPEED_CLASSES["radar"]


@pytest.mark.parametrize("controller", [
    {"kind": "PID"}, {"kind": "pid"}, {"kind": "PI"}, {"kind": "P"}, {"kind": "PID", "gains": "textbook"},
    {"kind": "PI", "gains": "relay", "form": "positional"},
    {"kind": "PID", "derivative_on_measurement": True},
    {"kind": "PID", "gains": "manual", "kp": 0.4, "ki": 1.5},
    {"kind": "aog_pi"}, {"kind": "ff_pi"}, {"kind": "ff_pi", "params": {"feedforward": "model"}},
    {"kind": "smith"}, {"kind": "fuzzy_pid"}, {"kind": "fuzzy_pid", "params": {"gains": "textbook"}},
    {"kind": "ideal"},
])
def test_every_kind_resolves_to_numbers_that_run_the_same_loop_bit_for_bit(controller):
    sc = with_changes(load(None), controller=controller)
    resolved = as_run(sc)
    cfg = resolved.controller
    if sc.controller.kind in ("P", "PI", "PID", "pid"):
        assert cfg.kind == sc.controller.kind.upper()
        assert cfg.gains == "manual" and cfg.kp is not None
        assert (cfg.ki is not None) == ("I" in cfg.kind) and (cfg.kd is not None) == ("D" in cfg.kind)
    else:   # every parameter of the kind, none left to a default that depends on the plant
        assert set(cfg.params) >= {k for k, v in cfg.kind_params().to_dict().items() if v is not None}
        assert None not in cfg.params.values()
        assert cfg.params.get("gains", "manual") == "manual"
        assert cfg.params.get("model_delay_s", cfg.params.get("reference_delay_s", 0.0)) is not None
    for a, b in zip(loop_output(sc), loop_output(resolved), strict=True):
        assert np.array_equal(a, b)
    assert as_run(resolved) == resolved     # idempotent


def test_auto_look_ahead_resolves_to_the_seconds_the_core_starts_with():
    sc = with_changes(load(None), controller={"look_ahead_s": "auto"})
    resolved = as_run(sc)
    assert isinstance(resolved.controller.look_ahead_s, float)
    assert resolved.controller.look_ahead_s == initial_look_ahead_s(sc, plant_for(sc))
    assert resolved.controller.look_ahead_s > sc.implement.delivery_delay_s   # the loop's lag added


def test_a_python_controller_keeps_its_own_params():
    sc = load(os.path.join(REPO, "scenarios", "my_controller.toml"))
    resolved = as_run(sc)
    assert resolved.controller.params == sc.controller.params
    assert resolved.controller.file == sc.controller.file and os.path.isabs(resolved.controller.file)


def test_a_python_controllers_auto_look_ahead_is_left_to_the_run_so_no_user_code_runs(tmp_path):
    (tmp_path / "boom.py").write_text("raise SystemExit('user code ran')\n")
    sc = with_changes(load(None), controller={"kind": "python", "file": str(tmp_path / "boom.py"),
                                              "class": "C", "look_ahead_s": "auto"})
    assert as_run(sc).controller.look_ahead_s == "auto"   # building a world never runs the file


@pytest.mark.parametrize("kind", sorted(GNSS_CLASSES))
def test_gnss_grades_resolve_to_their_class_and_overrides_stay(kind):
    cfg = GnssConfig(kind=kind)
    assert (cfg.resolved().sigma_m, cfg.resolved().tau_s) == GNSS_CLASSES[kind]
    assert (cfg.resolved().sigma, cfg.resolved().tau) == (cfg.sigma, cfg.tau)
    own = GnssConfig(kind=kind, sigma_m=0.05)
    assert own.resolved().sigma_m == 0.05 and own.resolved().tau_s == GNSS_CLASSES[kind][1]


@pytest.mark.parametrize("kind", sorted(SPEED_CLASSES))
def test_speed_sensor_kinds_resolve_to_their_class_and_read_the_same(kind):
    cfg = SpeedSensorConfig(kind=kind)
    resolved = cfg.resolved()
    assert (resolved.noise_pct, resolved.bias_pct) == SPEED_CLASSES[kind]
    assert (resolved.sigma, resolved.bias) == (cfg.sigma, cfg.bias)   # the same floats, not nearly
    assert SpeedSensorConfig(kind=kind, bias_pct=-2.0).resolved().bias_pct == -2.0


def without_origin(sc):
    """`sc` without where it was read from, the files it names as absolute paths."""
    files = {key: dataclasses.replace(spec, file=os.path.abspath(sc.path(spec.file)))
             for key, spec in (("field", sc.field), ("map", sc.map)) if spec.file is not None}
    return dataclasses.replace(sc, source="", base_dir="", **files)


@pytest.mark.parametrize("name, changes", [
    ("default", {}),
    ("default", {"controller": {"kind": "fuzzy_pid", "look_ahead_s": "auto", "look_ahead_tune": 0.3},
                 "gnss": {"kind": "dgps"}, "speed_sensor": {"kind": "wheel"},
                 "implement": {"sections": 4, "section_widths_m": [3.0, 3.5, 2.5, 3.0]},
                 "description": 'a "quoted"\nline'}),
    ("quick_rectangle.toml", {"controller": {"kind": "smith"}, "timing": {"max_sim_time_s": 5000.0}}),
    ("geojson_field_geotiff_map.toml", {}),
    ("my_controller.toml", {}),
])
def test_a_scenario_written_as_toml_reads_back_to_itself_resolved_or_not(tmp_path, name, changes):
    spec = name if name == "default" else os.path.join(REPO, "scenarios", name)
    sc = with_changes(load(spec), **changes) if changes else load(spec)
    for scenario in (sc, as_run(sc)):
        path = tmp_path / "as_run.toml"
        path.write_text(to_toml(scenario))
        back = load(str(path))   # from another folder: the files it names are absolute
        assert without_origin(back) == without_origin(scenario)
    assert without_origin(as_run(parse(to_toml(as_run(sc))))) == without_origin(as_run(sc))


def test_table_checks_name_file_table_key_and_value():
    with pytest.raises(ScenarioError, match=r"^f\.toml: \[map\] unknown key 'x' \(known: a, b\)$"):
        no_unknown({"a": 1, "x": 2}, {"a", "b"}, "f.toml", "map")
    with pytest.raises(ScenarioError, match=r"^f\.toml: seed must be int, got True$"):
        typed({"seed": True}, "seed", int, "f.toml", "")
    assert typed({}, "seed", int, "f.toml", "", default=1) == 1
    assert typed({"name": "n"}, "name", str, "f.toml", "") == "n"
