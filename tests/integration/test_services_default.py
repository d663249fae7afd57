"""The whole built-in default scenario (~177,000 ticks) through the services in lockstep gives the same
metrics as `vrsim run` to 1e-9 relative: vehicle (SUMO + GNSS) -> controller -> monitor (SQLite) ->
report, every process separate, on loopback."""

from __future__ import annotations

import json
import subprocess

from tests.conftest import VRSIM
from tests.integration.test_services_support import MONITOR_KEYS, ServeAll, assert_same_summary


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
    assert report["missing_ticks"] == [] and report["complete"] is True
    assert report["ticks"] == expected["ticks"] > 100_000
    assert_same_summary(report, expected, MONITOR_KEYS)
