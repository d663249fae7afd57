"""The twin of a real machine, through the real executable: `vrsim fit` on the John Deere per-section
export writes machine_fit.toml, which `vrsim replay`, `run`, `compare` and `tune` take with --machine;
the fitted twin reproduces the logged rate better than the target as a prediction and better than the
unfitted machine; `vrsim tune --log` tunes the controller on the log's own drive."""

from __future__ import annotations

import json
import os
import subprocess
import tomllib

import pytest

from tests.conftest import SHARED, VRSIM

EACH_SECTION = os.path.join(SHARED, "data", "asapplied", "jd-gen4-application-point-eachsection.zip")
ONE_HERTZ = os.path.join(SHARED, "data", "asapplied", "jd-gen4-application-point-onehertz.zip")
# The sprayer example with the log's rate (about 10 gal/ac) at the log's speed: the fitted boom can apply it.
FIELD = ["scenarios/sprayer.toml", "--set", "map.params.mean_kg_ha=93.5", "--set",
         "map.params.std_kg_ha=10.0", "--set", "tractor.working_speed_m_s=6.6"]


def vrsim(*args, timeout=600):
    return subprocess.run([VRSIM, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The twin fitted on the first half of the export, judged on the second and on the 1 Hz export of
    the same job, as a user's other logs would judge it."""
    out = tmp_path_factory.mktemp("fit")
    p = vrsim("fit", EACH_SECTION, "--split", "0.5", "--validate", ONE_HERTZ, "--out", out, "--json")
    assert p.returncode == 0, p.stderr
    return out, json.loads(p.stdout)


def replayed(*args):
    p = vrsim("replay", EACH_SECTION, "--json", *args)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def test_fit_writes_the_machine_and_prints_each_parameter_with_its_uncertainty(fitted):
    out, summary = fitted
    with open(out / "machine_fit.toml", "rb") as fh:
        machine = tomllib.load(fh)
    assert set(machine) == {"implement", "product", "controller", "response"}
    for name, p in summary["parameters"].items():
        assert p["unit"] and (p["std"] is not None) == p["identified"], name
        assert p["identified"] or p["why_not"], name
        if name in machine["response"]:
            assert machine["response"][name] == pytest.approx(p["value"])
    assert summary["rise_time_constant_s"] > 0 and summary["fall_time_constant_s"] > 0


def test_the_fitted_twin_reproduces_the_log_better_than_the_target_and_the_unfitted_machine(fitted):
    out, _ = fitted
    twin = replayed("--machine", out / "machine_fit.toml")
    unfitted = replayed()
    assert twin["mae_vs_log"] <= 0.75 * twin["target_mae_vs_log"]
    assert twin["mae_vs_log"] < unfitted["mae_vs_log"]
    assert twin["pass_start_mae_vs_log"] < twin["pass_start_target_mae_vs_log"]


def test_fit_judges_the_part_held_out_and_another_log(fitted):
    _, summary = fitted
    judged, unfitted = summary["judged"], summary["default_machine"]["judged"]
    assert summary["fitted"]["compared_records"] + judged["compared_records"] == 3902
    assert judged["pass_start_compared_records"] == 0   # the only pass start is in the first half
    assert judged["mae_vs_log"] < min(judged["target_mae_vs_log"], unfitted["mae_vs_log"])
    validated = summary["validated"]
    assert validated["records"] == 780 and validated["mae_vs_log"] < validated["target_mae_vs_log"]


def test_run_and_compare_take_the_machine(fitted, tmp_path):
    out, summary = fitted
    p = vrsim("run", *FIELD, "--machine", out / "machine_fit.toml", "--json", "--quiet",
              "--out", tmp_path / "run")
    assert p.returncode == 0, p.stderr
    ran = json.loads(p.stdout)
    response = ran["scenario_config"]["response"]
    assert response["dead_time_s"] == pytest.approx(summary["parameters"]["dead_time_s"]["value"])
    assert ran["scenario_config"]["implement"]["sections"] == 11
    p = vrsim("compare", *FIELD, "--machine", out / "machine_fit.toml", "--controller", "PI", "--json",
              "--quiet", "--out", tmp_path / "compare")
    assert p.returncode == 0, p.stderr


def test_tune_on_the_log_beats_the_machines_own_gains_and_its_logged_error(fitted, tmp_path):
    out, _ = fitted
    p = vrsim("tune", "--log", EACH_SECTION, "--machine", out / "machine_fit.toml", "--param", "kp=0.05:5",
              "--param", "ki=0.1:30", "--objective", "twin_mae_vs_target", "--budget", "30", "--json",
              "--quiet", "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    result = json.loads(p.stdout)
    assert result["best_objective"] < result["baseline"]["twin_mae_vs_target"]
    assert result["best_objective"] < result["baseline"]["target_mae_vs_log"]   # the machine's own error
    gains = result["best"]
    again = replayed("--machine", out / "machine_fit.toml", "--set", f"controller.kp={gains['kp']!r}",
                     "--set", f"controller.ki={gains['ki']!r}")
    assert again["twin_mae_vs_target"] == pytest.approx(result["best_objective"])


@pytest.mark.parametrize("args, message", [
    (["fit", EACH_SECTION, "--split", "1.5"], "--split"),
    (["fit", EACH_SECTION, "--start-s", "0", "--end-s", "2"], "too short to replay"),
    (["tune", "--log", EACH_SECTION, "--param", "kp=0.1:1", "--objective", "mae_kg_ha"], "on a log"),
    (["tune", "--param", "kp=0.1:1", "--objective", "mae_kg_ha"], "--log"),
    (["fit", EACH_SECTION, "--scenario", "default"], "logs a volume rate (gal/ac)"),
])
def test_bad_input_exits_2_with_one_line(args, message, tmp_path):
    p = vrsim(*args, "--out", tmp_path)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert message in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_a_machine_file_with_a_wrong_key_is_named_in_the_one_line(tmp_path):
    bad = tmp_path / "machine_fit.toml"
    bad.write_text("[response]\ndead_time = 1.0\n")
    for command in (["replay", ONE_HERTZ], ["run", "--check"]):
        p = vrsim(*command, "--machine", bad)
        assert p.returncode == 2 and p.stderr.count("\n") == 1, p.stderr
        assert f"{bad}: [response] unknown key 'dead_time'" in p.stderr


def test_tune_on_a_log_prints_the_twins_figures(fitted, tmp_path):
    out, _ = fitted
    p = vrsim("tune", "--log", EACH_SECTION, "--machine", out / "machine_fit.toml", "--param", "kp=0.05:5",
              "--objective", "twin_mae_vs_target", "--budget", "5", "--quiet", "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    row = next(line for line in p.stdout.splitlines() if "twin's error against its target [gal/ac]" in line)
    assert "-" not in row.split("]")[1] and row.rstrip().endswith("<")


def test_a_fit_that_does_not_converge_exits_3_with_its_best_figures(tmp_path, monkeypatch, capsys):
    from vrsim.services.cli.main import main
    from vrsim.services.sim import fit

    monkeypatch.setattr(fit, "MAX_EVALUATIONS", 2)   # the optimizer stops before it converges
    code = main(["fit", EACH_SECTION, "--out", str(tmp_path), "--json"])
    assert code == 3
    summary = json.loads(capsys.readouterr().out)
    assert summary["converged"] is False and summary["fitted"]["mae_vs_log"] is not None
    assert os.path.exists(tmp_path / "machine_fit.toml")
