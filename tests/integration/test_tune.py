"""vrsim tune end to end (real SUMO, the real executable): a small search writes a [controller] table a
scenario can include and the objective's history; bad input exits 2 naming what."""

import csv
import json
import os
import subprocess
import tomllib

import pytest

from tests.conftest import ROOT, VRSIM
from tests.integration.test_variants import FIELD
from vrsim.services.sim import scenario
from vrsim.services.sim.run import run


def vrsim(*args):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=600)


def test_tune_writes_a_controller_table_that_a_scenario_runs_to_the_same_figure(tmp_path):
    (tmp_path / "f.toml").write_text(FIELD)
    p = vrsim("tune", str(tmp_path / "f.toml"), "--controller", "PI", "--param", "kp=0.05:2",
              "--param", "ki=0.1:10", "--objective", "mae_kg_ha", "--budget", "12", "--json",
              "--out", str(tmp_path / "out"))
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["evaluations"] <= 12 and out["tuned"]["mae_kg_ha"] <= out["baseline"]["mae_kg_ha"] + 1e-9
    table = (tmp_path / "out" / "best_controller.toml").read_text()
    cfg = tomllib.loads(table)["controller"]
    assert cfg["kind"] == "PI" and cfg["gains"] == "manual" and cfg["kp"] == pytest.approx(out["best"]["kp"])
    (tmp_path / "tuned.toml").write_text(FIELD + "\n" + table)
    again = run(scenario.load(str(tmp_path / "tuned.toml")))
    assert again.summary["mae_kg_ha"] == pytest.approx(out["best_objective"], rel=1e-9)
    with open(tmp_path / "out" / "history.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == out["evaluations"] and set(rows[0]) >= {"evaluation", "generation", "kp", "ki",
                                                                "mae_kg_ha", "best_so_far"}
    best = [float(r["best_so_far"]) for r in rows]
    assert best == sorted(best, reverse=True) and best[-1] == pytest.approx(out["best_objective"], rel=1e-9)


@pytest.mark.parametrize("args, message", [
    (["--controller", "PIDX", "--param", "kp=0.1:1"], "PIDX"),
    (["--controller", "PID", "--param", "kq=0.1:1"], "'kq'"),
    (["--controller", "aog_pi", "--param", "nope=0.1:1"], "nope"),
    (["--controller", "PID", "--param", "kp=1:0.5"], "LOW must be < HIGH"),
    (["--controller", "PID", "--param", "kp=0.1:1", "--objective", "speed"], "'speed'"),
    (["--controller", "PID", "--param", "kp=0.1:1", "--budget", "0"], "--budget"),
])
def test_bad_input_exits_2_naming_what(args, message):
    if "--objective" not in args:
        args = [*args, "--objective", "mae_kg_ha"]
    p = vrsim("tune", "default", *args)
    assert p.returncode == 2, p.stderr
    assert message in p.stderr and len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr


MY_CONTROLLER = os.path.join(ROOT, "scenarios", "my_controller.toml")
KP = ["--param", "kp_a_per_rpm=0.0005:0.005", "--objective", "mae_kg_ha", "--budget", "8", "--json"]


def _best_python_controller(out_dir) -> dict:
    cfg = tomllib.loads((out_dir / "best_controller.toml").read_text())["controller"]
    assert cfg["kind"] == "python" and cfg["class"] == "MyController" and os.path.isfile(cfg["file"])
    assert 0.0005 <= cfg["params"]["kp_a_per_rpm"] <= 0.005 and cfg["params"]["ki_a_per_rpm_s"] == 0.008
    return cfg


def test_tune_searches_the_scenarios_own_python_controller(tmp_path):
    p = vrsim("tune", MY_CONTROLLER, *KP, "--out", str(tmp_path / "out"))
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["controller"] == "python" and 1 <= out["evaluations"] <= 8
    assert out["tuned"]["mae_kg_ha"] <= out["baseline"]["mae_kg_ha"] + 1e-9
    assert out["best"]["kp_a_per_rpm"] == _best_python_controller(tmp_path / "out")["params"]["kp_a_per_rpm"]


def test_tune_takes_a_controller_spec_file_whose_best_a_scenario_runs_to_the_same_figure(tmp_path):
    (tmp_path / "f.toml").write_text(FIELD)
    p = vrsim("tune", str(tmp_path / "f.toml"), "--controller", MY_CONTROLLER, *KP,
              "--out", str(tmp_path / "out"))
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    _best_python_controller(tmp_path / "out")
    table = (tmp_path / "out" / "best_controller.toml").read_text()
    (tmp_path / "tuned.toml").write_text(FIELD + "\n" + table)
    again = run(scenario.load(str(tmp_path / "tuned.toml")))     # one at a time, as a field run
    assert again.summary["mae_kg_ha"] == pytest.approx(out["best_objective"], rel=1e-9)


@pytest.mark.slow
def test_tune_the_default_field_with_the_example_spec_file(tmp_path):
    """The issue's command as given (the default field's 177,000 ticks through a Python class)."""
    p = vrsim("tune", "default", "--controller", MY_CONTROLLER, *KP, "--out", str(tmp_path / "out"))
    assert p.returncode == 0, p.stderr
    _best_python_controller(tmp_path / "out")


@pytest.mark.parametrize("args, message", [
    (["--controller", "nope.toml"], "nope.toml"),
    (["--param", "kq_a_per_rpm=0.1:1"], "rejected its params"),
])
def test_a_python_controllers_bad_input_exits_2(tmp_path, args, message):
    if "--param" not in args:
        args = [*args, "--param", "kp_a_per_rpm=0.001:0.002"]
    p = vrsim("tune", MY_CONTROLLER, *args, "--objective", "mae_kg_ha")
    assert p.returncode == 2, p.stderr
    assert message in p.stderr and len(p.stderr.strip().splitlines()) == 1
