"""The real services behind a router enforcing `services.bus.security`: each `vrsim serve NAME` logs in
with its own generated configuration (``--zenoh-config <state>/<name>.json5``), a whole lockstep run
goes through under the access-control rules, the operator drives it, and a viewer or another service
cannot stop it or change what the monitor stored."""

from __future__ import annotations

import json
import os
import subprocess
import time

import orjson
import pytest

from tests.conftest import VRSIM
from tests.integration.secure_bus import K, P, SecureRouter, wait_until
from tests.integration.test_services_support import write_field_files

SERVICES = ("map", "vehicle", "controller", "monitor", "scenario")


def query(session, selector: str, payload: bytes | None = None, timeout_s: float = 60.0):
    """(ok, JSON) of the one reply; (None, None) when there is none (refused by the router)."""
    kwargs = {"timeout": timeout_s} | ({"payload": payload} if payload is not None else {})
    got = list(session.get(selector, **kwargs))
    if not got:
        return None, None
    assert len(got) == 1, selector
    if got[0].ok is not None:
        return True, json.loads(got[0].ok.payload.to_bytes())
    return False, json.loads(got[0].err.payload.to_bytes())


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("secure-services"))
    router = SecureRouter(folder)
    procs = []
    try:
        for name in SERVICES:
            extra = ["--db", os.path.join(folder, "monitor.sqlite")] if name == "monitor" else []
            argv = [VRSIM, "serve", name, "--zenoh-config", router.config_file(name), *extra]
            procs.append(subprocess.Popen(argv, cwd=folder, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL))
        router.files = write_field_files(folder)
        operator = router.session("operator")

        def all_alive():
            ok, status = query(operator, f"{P}/scenario/status", timeout_s=5)
            return bool(ok) and not status["missing"]

        assert wait_until(all_alive, timeout_s=60), "services did not come up under the ACL"
        yield router
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.wait(timeout=20)
        router.stop()


def test_operator_runs_a_scenario_and_nobody_else_can_change_it(live):
    operator, viewer = live.session("operator"), live.session("viewer")
    scenario = live.files["scenario"]
    selector = f"{P}/scenario/start?source={scenario};base_dir={os.path.dirname(scenario)}"
    with open(scenario, "rb") as fh:
        body = fh.read()
    assert query(viewer, selector, body) == (None, None)
    ok, started = query(operator, selector, body)
    assert ok, started
    # a viewer cannot stop it; the vehicle, controller and monitor keep it going
    assert query(viewer, f"{P}/scenario/stop") == (None, None)
    assert query(viewer, f"{K}/vehicle/stop") == (None, None)

    def finished():
        return query(operator, f"{P}/scenario/status")[1]["state"] == "finished"

    assert wait_until(finished, timeout_s=120)
    ok, report = query(viewer, f"{K}/report")
    assert ok and report["ticks"] > 100, report
    # forged records for the finished run, from everyone but their publisher
    zero = {"target_shaft_rpm": 0.0, "shaft_rpm": 0.0, "shaft_rev": 0.0, "current_a": 0.0}
    forged = orjson.dumps([{"run_id": started["run_id"], "tick": t, "time_s": t * 0.05, **zero}
                           for t in range(report["ticks"])])
    for user in ("viewer", "operator", "vehicle", "scenario", "map"):
        live.session(user).put(f"{K}/shaft", forged)
    time.sleep(1.0)
    again = query(viewer, f"{K}/report")[1]
    assert {k: again[k] for k in again if k != "stage_s"} == {k: report[k] for k in report if k != "stage_s"}


def test_vrsim_query_logs_in_with_a_generated_configuration(live):
    done = subprocess.run([VRSIM, "query", "scenario/status", "--zenoh-config", live.config_file("viewer")],
                          capture_output=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["missing"] == []
    refused = subprocess.run([VRSIM, "query", "scenario/stop", "--zenoh-config", live.config_file("viewer")],
                             capture_output=True, timeout=60)
    assert refused.returncode == 2 and b"no reply" in refused.stderr, refused.stderr
