"""vrsim sweep when its cluster fails it: a Dask scheduler and a worker started as separate processes
(127.0.0.1), then killed mid-sweep; a plan too big to start without a word. Real SUMO runs, the real
vrsim executable."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import ROOT, VRSIM
from tests.integration.test_sweep import SCENARIO, _stop, vrsim
from vrsim.services.outputs.sweep_results import _read_rows

# Eight runs, one task per run (not all axes are controller.* keys), on a field long enough that a warm
# worker takes about 0.8 s a run (test_sweep's 72 m x 150 m takes 0.07 s: all eight were done before
# the table's first flush, 1 s in, and nothing was left to cut): on one worker the sweep lasts long
# enough to be cut after its first row.
FIELD = ("width_m = 72.0, length_m = 150.0", "width_m = 144.0, length_m = 1200.0")
SWEEP = """
scenarios = ["q.toml"]
seeds = [1]
[axes]
"controller.kp" = [0.3, 0.4, 0.5, 0.6]
"field.headland_passes" = [1, 2]
"""
ENV = dict(os.environ, PYTHONPATH=ROOT)


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "q.toml").write_text(SCENARIO.replace(*FIELD))
    (tmp_path / "s.toml").write_text(SWEEP)
    return tmp_path


def _scheduler(folder, name):
    """A scheduler process on 127.0.0.1 and its address."""
    path = folder / f"{name}.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
         "--no-dashboard", "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV, cwd=str(folder))
    deadline = time.monotonic() + 60
    while not path.exists() and time.monotonic() < deadline:
        assert proc.poll() is None, "the scheduler exited"
        time.sleep(0.2)
    return proc, json.loads(path.read_text())["address"]


def _worker(folder, address, *extra):
    return subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1", "--host",
         "127.0.0.1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0", *extra],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV, cwd=str(folder))


def _sweep_until_first_row(folder, address, out, *extra):
    """`vrsim sweep` on `address` in the background, returned once its table holds a row."""
    proc = subprocess.Popen(
        [VRSIM, "sweep", str(folder / "s.toml"), "--scheduler", address, "--timeout", "60", "--out", str(out),
         "--no-dashboard", "--json", "--quiet", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    deadline = time.monotonic() + 60
    while not (out / "results.parquet").exists() and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.1)
    assert (out / "results.parquet").exists(), "no row within 60 s"
    return proc


def _kill(proc):
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=20)


def test_a_lost_scheduler_leaves_lost_rows_exit_3_and_resume_runs_exactly_those(folder):
    procs = []
    try:
        scheduler, address = _scheduler(folder, "first")
        procs += [scheduler, _worker(folder, address)]
        sweep = _sweep_until_first_row(folder, address, folder / "out")
        _kill(scheduler)
        stdout, stderr = sweep.communicate(timeout=60)
        assert sweep.returncode == 3, stderr
        outcome = json.loads(stdout)
        rows = _read_rows(str(folder / "out" / "results.parquet"))
        lost = {r["key"] for r in rows if r["status"] == "lost"}
        assert len(rows) == 8 and outcome["lost"] == len(lost) >= 1 and outcome["failed"] == 0
        assert {r["status"] for r in rows} <= {"ok", "lost"} and outcome["ok"] == 8 - len(lost)
        assert all(r["error"].startswith("lost: ") and r["mae_kg_ha"] is None
                   for r in rows if r["key"] in lost)
        assert stderr.splitlines() == [  # one line: no traceback of the client's reconnections
            f"vrsim sweep: {len(lost)} runs lost to the cluster (no result; their rows say lost): "
            f"--resume --out {folder / 'out'} runs them again"]

        scheduler, address = _scheduler(folder, "second")
        procs += [scheduler, _worker(folder, address)]
        p = vrsim("sweep", str(folder / "s.toml"), "--scheduler", address, "--timeout", "60", "--resume",
                  "--out", str(folder / "out"), "--no-dashboard", "--json", "--quiet")
        assert p.returncode == 0, p.stderr
        again = json.loads(p.stdout)
        assert (again["skipped"], again["ran"], again["ok"], again["lost"]) == (8 - len(lost), len(lost),
                                                                                  len(lost), 0)
    finally:
        for proc in reversed(procs):
            _stop(proc)
    after = _read_rows(str(folder / "out" / "results.parquet"))
    assert len(after) == 8 and {r["status"] for r in after} == {"ok"}
    assert {r["key"] for r in after} == {r["key"] for r in rows}
    assert {r["key"]: r["mae_kg_ha"] for r in after if r["key"] not in lost} == \
        {r["key"]: r["mae_kg_ha"] for r in rows if r["key"] not in lost}  # done rows kept as they were


def test_a_lone_worker_killed_is_said_and_no_worker_timeout_ends_the_sweep(folder):
    procs = []
    try:
        scheduler, address = _scheduler(folder, "scheduler")
        worker = _worker(folder, address, "--no-nanny")
        procs += [scheduler, worker]
        sweep = _sweep_until_first_row(folder, address, folder / "out", "--no-worker-timeout", "12")
        _kill(worker)
        # The sweep ends on its own once no worker joined for 12 s (its own clock: the lines below say
        # so); 120 s is the deadline of a hung one.
        stdout, stderr = sweep.communicate(timeout=120)
    finally:
        for proc in reversed(procs):
            _stop(proc)
    assert sweep.returncode == 3, stderr
    rows = _read_rows(str(folder / "out" / "results.parquet"))
    lost = [r for r in rows if r["status"] == "lost"]
    assert stderr.splitlines() == [
        "vrsim sweep: no worker on the cluster for 10 s: the sweep ends if none joins within 12 s "
        "(--no-worker-timeout)",
        f"vrsim sweep: {len(lost)} runs lost to the cluster (no result; their rows say lost): "
        f"--resume --out {folder / 'out'} runs them again"]
    assert len(rows) == 8 and json.loads(stdout)["lost"] == len(lost) >= 1
    assert {r["status"] for r in rows} <= {"ok", "lost"}
    assert any(r["error"] == "lost: no worker on the cluster for 12 s" for r in lost)


BIG = """
scenarios = ["q.toml"]
seeds = [1]
[axes]
"controller.kp" = { min = 0.2, max = 1.0, n = 101 }
"controller.ki" = { min = 0.5, max = 3.0, n = 100 }
"""


def test_a_plan_over_10000_runs_without_yes_and_without_a_terminal_exits_2_and_runs_nothing(folder):
    (folder / "big.toml").write_text(BIG)
    p = subprocess.run([VRSIM, "sweep", str(folder / "big.toml"), "--workers", "2", "--out",
                        str(folder / "out"), "--no-dashboard"],
                       capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert p.returncode == 2, p.stderr
    assert p.stderr == ("vrsim sweep: error: the plan has 10100 runs, about 2.7 h on 2 workers (the bench's "
                        "1.9 s per run of the default scenario): pass --yes to run it\n")
    assert p.stdout == "" and not (folder / "out").exists()


def test_a_plan_over_10000_runs_on_a_terminal_asks_and_a_no_runs_nothing(folder):
    import pty

    (folder / "big.toml").write_text(BIG)
    main, tty = pty.openpty()
    try:
        os.write(main, b"n\n")
        p = subprocess.run([VRSIM, "sweep", str(folder / "big.toml"), "--workers", "1", "--out",
                            str(folder / "out"), "--no-dashboard"],
                           capture_output=True, text=True, timeout=60, stdin=tty)
    finally:
        os.close(main)
        os.close(tty)
    assert p.returncode == 2, p.stderr
    assert p.stderr == ("vrsim sweep: the plan has 10100 runs, about 5.3 h on 1 worker (the bench's 1.9 s "
                        "per run of the default scenario). Run it? [y/N] vrsim sweep: error: not confirmed, "
                        "nothing run (--yes runs a plan this big without asking)\n")
    assert not (folder / "out").exists()
