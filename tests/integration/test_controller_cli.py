"""The controller lab through the real `vrsim` executable: `vrsim compare` (one shared drive; its PID run
is `vrsim run`'s), `vrsim controller analyze`, the example user-defined controller scenario, and the exit
codes of a user's controller that is broken (2) or crashes (1, with its file and line)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import pytest

from tests.conftest import ROOT, VRSIM
from tests.integration.test_services_support import without_clock

SMALL = """
name = "small"
seed = 4
[field]
rectangle = { width_m = 48.0, length_m = 120.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "zones"
params = { n_zones = 4 }
[output]
plots = false
html = false
"""
CRASHING = """\
import numpy as np


class Crashing:
    def __init__(self, params, loop, n):
        self.n = n

    def reset(self):
        pass

    def step(self, target_rpm, measured_rpm):
        if target_rpm[0] > 0:
            return np.full(self.n, {}["gone"])
        return np.zeros(self.n)

    def state(self):
        return {}

    def set_state(self, state):
        pass
"""


def vrsim(*args, env=None, cwd=None):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=600, env=env, cwd=cwd)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    path = tmp_path_factory.mktemp("lab")
    (path / "small.toml").write_text(SMALL)
    shutil.copy(os.path.join(ROOT, "scenarios", "my_controller.py"), path / "my_controller.py")
    specs = path / "specs"
    specs.mkdir()
    shutil.copy(os.path.join(ROOT, "scenarios", "my_controller.py"), specs / "my_controller.py")
    (specs / "mine.toml").write_text('[controller]\nkind = "python"\nfile = "my_controller.py"\n'
                                     'class = "MyController"\nlook_ahead_s = "auto"\n')
    (path / "crashing.py").write_text(CRASHING)
    return path


@pytest.fixture(scope="module")
def compared(folder):
    out = folder / "cmp"
    p = vrsim("compare", str(folder / "small.toml"), "--controller", "pid", "--controller", "smith",
              "--controller", str(folder / "specs" / "mine.toml"), "--json", "--quiet", "--out", str(out))
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout), out


def test_compare_json_has_one_run_per_spec_over_one_drive(compared, folder):
    doc, out = compared
    assert doc["scenario"] == "small"
    labels = [r["controller"] for r in doc["runs"]]
    assert labels == ["pid", "smith", str(folder / "specs" / "mine.toml")]
    ticks = {r["ticks"] for r in doc["runs"]}
    paths = {r["path_length_m"] for r in doc["runs"]}
    assert len(ticks) == 1 and len(paths) == 1 and ticks.pop() > 1000     # one drive, shared
    assert len({r["mae_kg_ha"] for r in doc["runs"]}) == 3                 # three different controllers
    page = (out / "compare.html").read_text()
    assert page.count("data:image/png;base64,") == 2 and page.count("<tr>") == 4
    assert "class=best" in page


def test_compares_pid_run_is_vrsim_runs(compared, folder):
    """The shared drive is the drive `vrsim run` would do: the PID's figures are identical."""
    p = vrsim("run", str(folder / "small.toml"), "--json", "--quiet", "--out", str(folder / "run"))
    assert p.returncode == 0, p.stderr
    expected = json.loads(p.stdout)
    got = dict(compared[0]["runs"][0])
    assert got.pop("controller") == "pid"
    assert set(got) == set(expected) - {"outputs_wall_s", "out_dir"}
    assert without_clock(got) == without_clock(expected)      # identical, not just close


def test_compare_table_marks_the_best_of_each_column(folder):
    p = vrsim("compare", str(folder / "small.toml"), "--controller", "PID", "--controller", "ideal",
              "--look-ahead", "auto", "--quiet", "--out", str(folder / "cmp2"))
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0].startswith("vrsim compare: small") and "MAE" in lines[1] and "in 10%" in lines[1]
    rows = {line.split()[0]: line for line in lines if line.split() and line.split()[0] in ("PID", "ideal")}
    assert set(rows) == {"PID", "ideal"} and "*" in rows["ideal"]
    assert "best in its column" in p.stdout and (folder / "cmp2" / "compare.html").is_file()


def test_compare_on_a_uniform_map_has_no_step_to_show(folder):
    """A map with no rate step: the page shows no step panels instead of failing (was exit 1)."""
    uniform = SMALL.replace('synthetic = "zones"\nparams = { n_zones = 4 }', 'synthetic = "uniform"')
    (folder / "uniform.toml").write_text(uniform)
    p = vrsim("compare", str(folder / "uniform.toml"), "--controller", "pid", "--controller", "ideal",
              "--quiet", "--out", str(folder / "cmp_uniform"))
    assert p.returncode == 0, p.stderr
    assert (folder / "cmp_uniform" / "compare.html").is_file()


@pytest.mark.parametrize("args, message", [
    (("--controller", "bang_bang"), "controller spec 'bang_bang': neither a kind"),
    (("--look-ahead", "soon"), "--look-ahead 'soon': must be seconds or auto"),
    (("--look-ahead", "99"), "look_ahead_s must be \"auto\" or a number in [0, 30] s, got 99.0"),
])
def test_compare_bad_input_exits_2_on_one_line(folder, args, message):
    p = vrsim("compare", str(folder / "small.toml"), *args, "--quiet", "--out", str(folder / "bad"))
    assert p.returncode == 2 and message in p.stderr and "Traceback" not in p.stderr, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_controller_analyze_text_json_and_pictures(folder):
    out = folder / "an"
    p = vrsim("controller", "analyze", str(folder / "small.toml"), "--json", "--out", str(out))
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    loop = doc["loop"]
    assert doc["kind"] == "PID" and loop["closed_loop_stable"] and loop["gain_margin"] > 1.4
    assert {os.path.basename(f) for f in doc["files"]} == {"bode.png", "step.png"}
    assert doc["look_ahead"]["used_s"] == 0.8 and doc["response"]["look_ahead_s"] > 0.2
    text = vrsim("controller", "analyze", str(folder / "small.toml"), "--out", str(out))
    assert text.returncode == 0, text.stderr
    assert f"{loop['gain_margin']:.3f}" in text.stdout
    assert f"{loop['phase_margin_deg']:.1f} deg" in text.stdout
    assert f"{doc['look_ahead']['auto_s']:.3f} s" in text.stdout


def test_the_example_user_controller_scenario_runs(tmp_path):
    p = vrsim("run", os.path.join(ROOT, "scenarios", "my_controller.toml"), "--json", "--quiet", "--out",
              str(tmp_path))
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["scenario"] == "my_controller" and summary["transitions"] > 10


def user_scenario(folder, cls: str, file: str = "crashing.py") -> str:
    path = folder / f"user-{cls}.toml"
    path.write_text(SMALL + f'[controller]\nkind = "python"\nfile = "{file}"\nclass = "{cls}"\n')
    return str(path)


def test_a_crash_in_user_code_exits_1_with_its_file_and_line(folder):
    path = user_scenario(folder, "Crashing")
    p = vrsim("run", path, "--quiet", "--out", str(folder / "crash"))
    assert p.returncode == 1 and "Traceback" not in p.stderr
    line = CRASHING.splitlines().index('            return np.full(self.n, {}["gone"])') + 1
    assert re.search(rf"crashing.py:{line}: Crashing.step raised KeyError: 'gone'", p.stderr), p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    debug = vrsim("run", path, "--quiet", "--out", str(folder / "crash"),
                  env={**os.environ, "VRSIM_DEBUG": "1"})
    assert debug.returncode == 1 and "Traceback" in debug.stderr and f'line {line}, in step' in debug.stderr


def test_a_broken_user_class_exits_2_naming_file_and_class(folder):
    p = vrsim("run", user_scenario(folder, "Missing"), "--quiet", "--out", str(folder / "missing"))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "crashing.py: no class 'Missing' (classes in it: Crashing)" in p.stderr
    assert "user-Missing.toml: [controller]" in p.stderr
