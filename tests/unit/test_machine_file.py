"""A machine file (machine_fit.toml): its tables as overrides of any scenario, checked as a scenario
file's keys are, in a sweep file too (its [set] and axes over them)."""

from __future__ import annotations

import pytest

from vrsim.common import ScenarioError
from vrsim.services.sim.overrides import machine_overrides
from vrsim.services.sim.scenario import load
from vrsim.services.sim.sweep.design import parse_sweep, plan

MACHINE = """
[controller]
kind = "PID"
gains = "manual"
kp = 0.5
ki = 2.0
kd = 0.0

[response]
dead_time_s = 0.8
opening_peak_pct = 40.0
opening_time_constant_s = 1.5
"""


def test_a_machine_file_sets_its_keys_on_a_scenario(tmp_path):
    path = tmp_path / "machine_fit.toml"
    path.write_text(MACHINE)
    scenario = load("default", machine_overrides(str(path)))
    assert scenario.response.dead_time_s == 0.8 and scenario.response.opening_peak_pct == 40.0
    assert scenario.controller.kp == 0.5


@pytest.mark.parametrize("text, message", [
    ("dead_time_s = 1.0\n", "a machine file holds tables"),
    ("[response\n", "not a machine file"),
])
def test_a_bad_machine_file_is_refused_naming_it(tmp_path, text, message):
    path = tmp_path / "m.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=message):
        machine_overrides(str(path))


def test_a_key_of_the_machine_file_the_scenario_has_not_is_refused_as_a_files_key(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text("[response]\ndead_time = 1.0\n")
    with pytest.raises(ScenarioError, match=r"\[response\].*dead_time"):
        load("default", machine_overrides(str(path)))


def test_a_sweep_runs_on_the_machine_with_its_axes_over_it(tmp_path):
    (tmp_path / "machine_fit.toml").write_text(MACHINE)
    sweep = parse_sweep('scenarios = ["default"]\nmachine = "machine_fit.toml"\n'
                        '[axes]\n"controller.kp" = [0.2, 0.9]\n', "s.toml", str(tmp_path))
    runs = [spec.load() for spec in plan(sweep)]
    assert sorted(sc.controller.kp for sc in runs) == [0.2, 0.9]
    assert all(sc.response.dead_time_s == 0.8 and sc.controller.ki == 2.0 for sc in runs)
