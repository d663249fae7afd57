"""Completeness that tells the truth, with real processes on 127.0.0.1: scenario control announces each
run's end to the monitor, and the report says ``complete: true`` only for a finished run with every
tick stored; a stopped run says so, a monitor killed mid-run and restarted after it names the unstored
tail (and ``vrsim report --db`` warns); a viewer reading ``report`` in a loop is answered and refused in
turn while a lockstep run completes (how little the loop slows the default scenario's run is a figure of
`bench/bench_services.py`, ``zenoh_report_loop_default_slowdown``). The tests share one `vrsim serve all`
and run in file order."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import threading
import time

import pytest

from tests.conftest import VRSIM
from tests.integration.test_services_support import ServeAll, open_client

SCENARIO = os.path.join(os.path.dirname(__file__), "..", "..", "scenarios", "quick_rectangle.toml")
K = "vrsim/tractor1"


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("complete"))
    shutil.copy(SCENARIO, os.path.join(folder, "quick.toml"))
    server = ServeAll(folder)
    server.extra = []
    try:
        server.wait_ready()
        yield server
    finally:
        server.stop()
        for proc in server.extra:
            proc.terminate()
            proc.wait(timeout=10)


def start(net, *params: str) -> dict:
    with open(os.path.join(net.folder, "quick.toml"), "rb") as fh:
        selector = ";".join(["vrsim/scenario/start?source=quick.toml", f"base_dir={net.folder}", *params])
        ok, reply = net.query(selector, fh.read())
    assert ok, reply
    return reply


def ended(net, run_id: str, state: str = "finished") -> dict:
    status = net.wait_status(lambda s: s["run_id"] == run_id and s["monitor_ticks"] == s["ticks"]
                             and s["state"] in ("finished", "stopped", "failed"), timeout_s=120)
    assert status["state"] == state, status
    return status


def report(net, run_id: str) -> dict:
    """The run's report, asked again after a moment while the monitor's limit on report queries (5 a
    second across all clients) refuses it, as its error says to: a viewer looping on report takes
    those turns too."""
    deadline = time.monotonic() + 60
    while True:
        ok, got = net.query(f"{K}/report?run_id={run_id}")
        if ok or "too many report queries" not in str(got) or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert ok, got
    return got


def missing(got: dict) -> int:
    return sum(last - first + 1 for first, last in got["missing_ticks"])


def test_a_finished_run_with_every_tick_is_complete(net):
    run = start(net)
    status = ended(net, run["run_id"])
    got = report(net, run["run_id"])
    assert (got["complete"], got["missing_ticks"], got["end_reason"]) == (True, [], "finished")
    assert got["ticks"] == status["ticks"] > 1000


def test_a_stopped_run_is_not_complete_and_says_stopped(net):
    run = start(net, "clock=realtime", "speed=5")
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["ticks"] >= 100)
    ok, stopped = net.query("vrsim/scenario/stop")
    assert ok and stopped["state"] == "stopped", stopped
    status = ended(net, run["run_id"], "stopped")
    got = report(net, run["run_id"])
    assert (got["complete"], got["missing_ticks"], got["end_reason"]) == (False, [], "stopped")
    assert got["ticks"] == status["ticks"] >= 100


def test_a_monitor_killed_mid_run_and_restarted_after_it_names_the_tail(net, tmp_path):
    run = start(net)
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["monitor_ticks"] > 2000)
    os.kill(net.children()["monitor"], signal.SIGKILL)
    status = net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["state"] == "finished"
                             and "monitor" in s["missing"], timeout_s=120)
    net.extra.append(net.serve("monitor", "--db", net.db))
    net.wait_status(lambda s: "monitor" in s["alive"], timeout_s=60)
    deadline = time.monotonic() + 30  # scenario control offers the end again until the monitor takes it
    while (got := report(net, run["run_id"]))["end_reason"] == "unknown":
        assert time.monotonic() < deadline, got
        time.sleep(0.5)
    total = status["ticks"]
    print(f"monitor killed mid-run: complete {got['complete']}, missing_ticks {got['missing_ticks']}, "
          f"end_reason {got['end_reason']}: {got['ticks']:,} of {total:,} ticks stored")
    assert got["complete"] is False and got["end_reason"] == "finished"
    assert got["missing_ticks"][-1][1] == total - 1  # the tail after the kill, up to the last tick
    assert got["ticks"] + missing(got) == total and 2000 < got["ticks"] < total
    cli = subprocess.run([VRSIM, "report", "--db", net.db, "--run", run["run_id"], "--out",
                          str(tmp_path / "report"), "--json"], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 0, cli.stderr
    warning = (f"vrsim report: warning: incomplete: {got['ticks']:,} of {total:,} ticks stored; "
               "reason finished")
    assert cli.stderr.splitlines() == [warning], cli.stderr
    summary = json.loads(cli.stdout)
    assert (summary["complete"], summary["missing_ticks"], summary["end_reason"]) == \
        (False, got["missing_ticks"], "finished")
    with open(tmp_path / "report" / "report.html") as fh:
        page = fh.read()
    banner = page.index(f'">{warning.split("warning: ", 1)[1]}</p>')  # the page's first lines
    assert page.index('<p class="incomplete"') < banner < page.index("<h1>")


def looped_drive_s(net, drive) -> tuple[float, dict]:
    """A lockstep run's drive time (``drive()``) while a viewer asks ``report`` in a loop, and the
    replies it got."""
    viewer = open_client(net.endpoint, net.state, user="viewer")
    done, replies = threading.Event(), {"ok": 0, "refused": 0}

    def loop():
        deadline = time.monotonic() + 120  # bounded: stops by itself
        while not done.is_set() and time.monotonic() < deadline:
            for reply in viewer.get(f"{K}/report", timeout=30):
                replies["ok" if reply.ok is not None else "refused"] += 1

    reader = threading.Thread(target=loop, daemon=True)
    reader.start()
    try:
        return drive(), replies
    finally:
        done.set()
        reader.join(timeout=60)
        viewer.close()


def test_a_viewer_reading_report_in_a_loop_is_answered_and_refused_while_the_run_completes(net):
    runs = []

    def drive() -> float:
        run = start(net)
        runs.append(ended(net, run["run_id"]))
        return runs[-1]["drive_s"]

    _, replies = looped_drive_s(net, drive)
    got = report(net, runs[0]["run_id"])
    print(f"lockstep run with a viewer looping on report: replies {replies}")
    assert replies["ok"] > 0 and replies["refused"] > 0, replies  # answered, and held to the limit
    assert (got["complete"], got["ticks"]) == (True, runs[0]["ticks"]), got


def default_drive_s(net, loop: bool = False) -> tuple[float, dict | None]:
    """The built-in default scenario (177,002 ticks) in lockstep: its drive time (and the loop's replies)."""
    def run() -> float:
        ok, started = net.query("vrsim/scenario/start")  # empty body: the default scenario
        assert ok, started
        drive_s = ended(net, started["run_id"])["drive_s"]
        report(net, started["run_id"])
        return drive_s

    if not loop:
        return run(), None
    return looped_drive_s(net, run)


def test_a_run_whose_vehicle_dies_is_interrupted(net):
    run = start(net, "clock=realtime", "speed=5")
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["monitor_ticks"] >= 100)
    os.kill(net.children()["vehicle"], signal.SIGKILL)
    net.wait_status(lambda s: "vehicle" in s["missing"], timeout_s=10)  # scenario control sees it go
    got = report(net, run["run_id"])
    print(f"vehicle killed mid-run: complete {got['complete']}, missing_ticks {got['missing_ticks']}, "
          f"end_reason {got['end_reason']}, {got['ticks']:,} ticks stored")
    assert (got["complete"], got["end_reason"]) == (False, "interrupted") and got["ticks"] >= 100


def test_a_router_crash_mid_run_leaves_the_end_unknown(net, tmp_path):
    net.extra.append(net.serve("vehicle"))  # the one killed above, started again by hand
    net.wait_status(lambda s: "vehicle" in s["alive"], timeout_s=60)
    run = start(net, "clock=realtime", "speed=5")
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["monitor_ticks"] >= 100)
    os.kill(net.proc.pid, signal.SIGKILL)  # `vrsim serve all` is the router (and scenario control)
    net.proc.wait(timeout=10)
    time.sleep(1.0)
    cli = subprocess.run([VRSIM, "report", "--db", net.db, "--run", run["run_id"], "--out",
                          str(tmp_path / "report"), "--json"], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 0, cli.stderr
    summary = json.loads(cli.stdout)
    print(f"router killed mid-run: complete {summary['complete']}, missing_ticks {summary['missing_ticks']}, "
          f"end_reason {summary['end_reason']}, {summary['ticks']:,} ticks stored")
    assert (summary["complete"], summary["end_reason"]) == (False, "unknown") and summary["ticks"] >= 100
    assert "(no end announced" in cli.stderr
