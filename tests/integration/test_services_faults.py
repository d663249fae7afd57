"""Faults with real processes: a monitor killed with SIGKILL and restarted on its database reports
over everything it had received; a killed controller or vehicle shows in scenario/status as missing
(waited for with a deadline generous for a loaded machine; how soon it shows on a quiet one is a
figure of `bench/bench_services.py`) and the monitor's records stay intact. The tests share one
`vrsim serve all` and run in file order."""

from __future__ import annotations

import os
import signal
import time

import pytest

from tests.integration.test_services_support import ServeAll, pid_alive, without_clock, write_field_files

WALL_KEYS = {"stage_s"}  # the only keys a report recomputes from the clock (wall time is stored)


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("faults"))
    files = write_field_files(folder)
    server = ServeAll(folder, "--map", files["map"])
    extra = []
    try:
        server.wait_ready()
        server.files, server.extra = files, extra
        yield server
    finally:
        server.stop()
        for proc in extra:
            proc.terminate()
            proc.wait(timeout=10)


def start(net, *params: str) -> dict:
    folder = os.path.dirname(net.files["scenario"])
    with open(net.files["scenario"], "rb") as fh:
        selector = ";".join([f"vrsim/scenario/start?source={net.files['scenario']}", f"base_dir={folder}",
                             *params])
        ok, reply = net.query(selector, fh.read())
    assert ok, reply
    return reply


MISSING_DEADLINE_S = 60.0  # a killed service shows within about 2 s on a quiet machine


def wait_missing(net, service: str, timeout_s: float = MISSING_DEADLINE_S) -> dict:
    """scenario/status once it lists `service` as missing."""
    deadline = time.monotonic() + timeout_s
    while True:
        ok, status = net.query("vrsim/scenario/status")
        assert ok, status
        if service in status["missing"]:
            return status
        assert time.monotonic() < deadline, f"{service} not reported missing within {timeout_s:g} s: {status}"
        time.sleep(0.05)


def report_without_clock(net) -> dict:
    ok, report = net.query("vrsim/tractor1/report")
    assert ok, report
    return without_clock(report, WALL_KEYS)


def test_restarted_monitor_lost_nothing(net):
    run = start(net)
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["state"] == "finished"
                    and s["monitor_ticks"] == s["ticks"])
    before = report_without_clock(net)
    monitor = net.children()["monitor"]
    os.kill(monitor, signal.SIGKILL)
    wait_missing(net, "monitor")
    net.extra.append(net.serve("monitor", "--db", net.db))
    net.wait_status(lambda s: "monitor" in s["alive"], timeout_s=30)
    assert report_without_clock(net) == before
    assert before["ticks"] > 1000


def settled_records(net, run_id: str, quiet_s: float = 1.0, timeout_s: float = 60.0) -> dict:
    """The monitor's record counts of `run_id` once they stop changing for `quiet_s` (records in flight
    when a service died still arrive after the run is reported failed: a loaded machine's monitor lags)."""
    deadline = time.monotonic() + timeout_s
    last, since = None, time.monotonic()
    while time.monotonic() < deadline:
        ok, stored = net.query(f"vrsim/tractor1/monitor/status?run_id={run_id}")
        assert ok, stored
        if stored != last:
            last, since = stored, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            return stored
        time.sleep(0.1)
    raise AssertionError(f"the monitor's records of {run_id} still changing after {timeout_s} s: {last}")


def test_killed_controller_is_reported_missing_and_records_stay(net):
    run = start(net, "clock=realtime", "speed=2")
    seen = net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["ticks"] >= 40)
    controller = net.children()["controller"]
    os.kill(controller, signal.SIGKILL)
    wait_missing(net, "controller")
    status = net.wait_status(lambda s: s["state"] == "failed", timeout_s=15)
    assert "no controller answered" in status["error"], status
    assert not pid_alive(controller)
    stored = settled_records(net, run["run_id"])
    # Every tick the vehicle got through was stored on all three streams; beyond them only what was in
    # flight when the controller died: poses sent without an answer (the batch in flight and the one it
    # failed on), and of the batch the controller was answering, its shaft records published before its
    # rate records (a SIGKILL between the two publishes left one shaft record more on a clean clone).
    # The vehicle counts a tick once its pose is sent, and waits for a batch's answer when it sends the
    # next: of the ticks seen before the kill, all but the last one in flight were answered (and a kill
    # on a loaded machine may come that soon: 39 of 40 stored on a clean clone).
    assert stored["ticks"] >= seen["ticks"] - 1 >= 39
    assert stored["pose_records"] - stored["ticks"] in (0, 1, 2)
    beyond = {stream: stored[f"{stream}_records"] - stored["ticks"] for stream in ("pose", "shaft", "rate")}
    assert 0 <= beyond["rate"] <= beyond["shaft"] <= beyond["pose"], stored
    report = report_without_clock(net)
    assert report["ticks"] == stored["ticks"]
    print(f"controller killed mid-run: complete {report['complete']}, "
          f"missing_ticks {report['missing_ticks']}, "
          f"end_reason {report['end_reason']}, {report['ticks']:,} of {status['ticks']:,} stored")
    # Not complete: the run failed; ticks the vehicle drove past the last controlled one are missing.
    assert (report["complete"], report["end_reason"]) == (False, "failed")
    assert report["ticks"] + sum(b - a + 1 for a, b in report["missing_ticks"]) == status["ticks"]


def test_hung_vehicle_is_reported_as_silent_not_dead(net):
    vehicle = net.children()["vehicle"]
    os.kill(vehicle, signal.SIGSTOP)
    try:
        ok, status = net.query("vrsim/scenario/status")
    finally:
        os.kill(vehicle, signal.SIGCONT)
    assert ok and status["state"] == "unknown" and "vehicle" in status["alive"], status
    assert status["error"] == "the vehicle service did not answer within 1 s", status


def test_killed_vehicle_is_reported_missing(net):
    vehicle = net.children()["vehicle"]
    os.kill(vehicle, signal.SIGKILL)
    status = wait_missing(net, "vehicle")
    assert status["state"] == "unknown" and status["error"] == "the vehicle service is not alive"
    assert set(status["missing"]) == {"vehicle", "controller"}
    with open(net.files["scenario"], "rb") as fh:
        ok, refused = net.query(f"vrsim/scenario/start?base_dir={os.path.dirname(net.files['scenario'])}",
                                fh.read())
    assert not ok and refused["error"].startswith("vrsim/scenario/start: cannot start, service(s) not alive: "
                                                  "vehicle, controller"), refused
