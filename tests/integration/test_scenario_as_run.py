"""The scenario as run, end to end (real SUMO): written out as TOML it loads and reruns to the same
figures; the run's outputs (`vrsim run --json`, summary.json, report.html) show its resolved values."""

import html
import json
import re
import subprocess

import numpy as np
import pytest

from tests.conftest import VRSIM
from vrsim.services.outputs.encode import dumps
from vrsim.services.sim.as_run import as_run
from vrsim.services.sim.run import run
from vrsim.services.sim.scenario import load, with_changes
from vrsim.services.sim.scenario_toml import to_toml

pytestmark = pytest.mark.integration

CLOCK_KEYS = {"wall_time_s", "realtime_factor", "stage_s"}
QUICK = "scenarios/quick_rectangle.toml"


@pytest.mark.parametrize("changes", [
    {},   # the paper's PID, RTK, radar
    {"controller": {"kind": "fuzzy_pid", "look_ahead_s": "auto"}, "gnss": {"kind": "dgps"},
     "speed_sensor": {"kind": "wheel"}},
])
def test_the_scenario_as_run_written_out_loads_and_reruns_to_the_same_figures(tmp_path, changes):
    first = run(with_changes(load(QUICK), **changes))
    shown = first.world.scenario
    assert shown == as_run(shown)   # the run consumed the scenario as run
    path = tmp_path / "as_run.toml"
    path.write_text(to_toml(shown))
    again = run(load(str(path)))
    assert dumps({k: v for k, v in first.summary.items() if k not in CLOCK_KEYS}) == \
        dumps({k: v for k, v in again.summary.items() if k not in CLOCK_KEYS})
    assert np.array_equal(first.as_applied.applied_kg_ha, again.as_applied.applied_kg_ha, equal_nan=True)
    assert np.array_equal(first.control["current_a"], again.control["current_a"])


def test_run_json_summary_json_and_the_report_show_the_values_used(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([VRSIM, "run", QUICK, "--out", str(out), "--json", "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout)["scenario_config"]
    written = json.loads((out / "summary.json").read_text())["scenario_config"]
    assert printed == written
    expected = as_run(load(QUICK))
    controller, gnss, speed = printed["controller"], printed["gnss"], printed["speed_sensor"]
    assert (controller["gains"], controller["kp"], controller["ki"], controller["kd"]) == \
        ("manual", expected.controller.kp, expected.controller.ki, expected.controller.kd)
    assert controller["look_ahead_s"] == expected.controller.look_ahead_s == 0.8
    assert (gnss["sigma_m"], gnss["tau_s"], speed["noise_pct"], speed["bias_pct"]) == (0.02, 10.0, 1.0, 0.0)
    page = (out / "report.html").read_text()
    settings = page[page.index("<h2>Settings as run</h2>"):page.index("<h2>Versions and seed</h2>")]
    for key, value in (("kp", controller["kp"]), ("sigma_m", 0.02), ("noise_pct", 1.0)):
        assert f"<td>{key}</td><td><code>{value!r}</code></td>" in settings
    assert "None" not in settings
    embedded = html.unescape(re.search(r"<pre>(.*?)</pre>", settings, re.S).group(1))
    assert embedded == to_toml(expected)
