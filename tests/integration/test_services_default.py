"""The whole built-in default scenario (~177,000 ticks) through the services in lockstep gives the same
metrics as `vrsim run` to 1e-9 relative: vehicle (SUMO + GNSS) -> controller -> monitor (SQLite) ->
report, every process separate, on loopback."""

from __future__ import annotations

import json
import math
import subprocess

import pytest

from tests.conftest import VRSIM
from tests.integration.test_services_support import ServeAll

WALL_KEYS = {"wall_time_s", "realtime_factor", "stage_s", "outputs_wall_s", "out_dir"}


def test_default_scenario_in_lockstep_matches_vrsim_run(tmp_path):
    server = ServeAll(str(tmp_path))
    try:
        server.wait_ready()
        ok, started = server.query("vrsim/scenario/start")  # empty body: the default scenario
        assert ok, started
        # Meanwhile, the same scenario in process (the machine has cores to spare while services wait).
        cli = subprocess.Popen([VRSIM, "run", "--json", "--quiet", "--out", str(tmp_path / "run")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        status = server.wait_status(lambda s: s["state"] in ("finished", "failed")
                                    and s["monitor_ticks"] == s["ticks"], timeout_s=300)
        assert status["state"] == "finished", status
        ok, report = server.query("vrsim/tractor1/report", timeout_s=120)
        assert ok, report
        out, err = cli.communicate(timeout=300)
        assert cli.returncode == 0, err
    finally:
        assert server.stop() == 0
    expected = json.loads(out)
    print(f"services: {status['ticks']} ticks in {status['drive_s']:.1f} s = "
          f"{status['ticks'] / status['drive_s']:.0f} ticks/s")
    assert set(report) == set(expected) | {"missing_ticks", "complete"}
    assert report["missing_ticks"] == [] and report["complete"] is True
    assert report["ticks"] == expected["ticks"] > 100_000
    for key, want in expected.items():
        if key in WALL_KEYS:
            continue
        if isinstance(want, float) and not math.isnan(want):
            assert report[key] == pytest.approx(want, rel=1e-9, abs=1e-12), key
        else:
            assert report[key] == want, key
