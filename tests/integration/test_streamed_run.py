"""The streamed run (`services.sim.streamed`, what `vrsim run` does): SUMO in a second process, the
track measured and controlled part by part, equal to the in-process run bit for bit (real SUMO)."""

import os
import signal

import numpy as np
import pytest

from common import ScenarioError
from services.outputs.encode import dumps
from services.sim.run import run
from services.sim.scenario import load, with_changes
from services.sim.streamed import DriveWorker, run_streamed

pytestmark = pytest.mark.integration

CLOCK_KEYS = {"wall_time_s", "realtime_factor", "stage_s"}
QUICK = "scenarios/quick_rectangle.toml"


def assert_same_run(a, b):
    assert dumps({k: v for k, v in a.summary.items() if k not in CLOCK_KEYS}) == \
        dumps({k: v for k, v in b.summary.items() if k not in CLOCK_KEYS})  # NaN as null: equal
    for key in a.track:
        assert np.array_equal(a.track[key], b.track[key]), key
    for key in a.control:
        assert np.array_equal(a.control[key], b.control[key]), key
    for name in ("measured_x_m", "measured_y_m", "measured_speed_m_s"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(a.as_applied.applied_kg_ha, b.as_applied.applied_kg_ha, equal_nan=True)


@pytest.mark.parametrize("changes", [
    {},
    # coverage section control remembers where product landed; the look-ahead tune re-looks ticks up
    {"implement": {"sections": 5, "section_control": "coverage"},
     "controller": {"kind": "smith", "look_ahead_s": "auto", "look_ahead_tune": 0.5},
     "gnss": {"kind": "dgps"}},
])
def test_in_parts_of_any_size_the_run_is_the_in_process_run(changes):
    sc = with_changes(load(QUICK), **changes)
    whole = run(sc)
    ticks = len(whole.track["time_s"])
    # parts far smaller than the control core's chunks, and one not dividing them
    streamed = run_streamed(sc, ticks_per_part=3001)
    assert ticks > 4 * 3001
    assert_same_run(whole, streamed)
    stage = streamed.summary["stage_s"]
    assert stage["sumo_s"] > 0 and stage["wait_s"] >= 0 and stage["control_s"] > 0


def test_in_parts_a_drive_per_section_runs_as_in_process():
    """``section_drives``: each drive's held rate and loop carried over, the tune re-looking ticks up.
    Several loops advance on the PID's shared lifted path, whose calls carry on from the last one's
    last product: the parts give the whole run's numbers bit for bit."""
    sc = with_changes(load(QUICK), implement={"kind": "section_drives"}, map={"policy": "hold"},
                      controller={"kind": "PID", "look_ahead_tune": 0.5})
    assert_same_run(run(sc), run_streamed(sc, ticks_per_part=3001))


def test_the_error_split_computed_beside_the_accounting_is_the_one_computed_after_it():
    from services.sim.error_split import error_split

    sc = load(QUICK)
    streamed = run_streamed(sc, error_split=True)
    assert streamed.reference_figures is not None
    whole = run(sc)
    assert whole.reference_figures is None
    assert error_split(streamed) == error_split(whole)


def test_progress_counts_every_tick_once():
    seen = []
    sc = load(QUICK)
    result = run_streamed(sc, progress=lambda done, total: seen.append((done, total)), ticks_per_part=5000)
    done = [d for d, _ in seen]
    assert done == sorted(done) and done[-1] == len(result.track["time_s"])
    assert all(d <= t for d, t in seen)


def test_a_drive_past_its_time_limit_is_the_in_process_runs_error():
    sc = with_changes(load(QUICK), tractor={"speed_variation_pct": 0.0, "working_speed_m_s": 0.5},
                      timing={"max_sim_time_s": 4000.0})
    with pytest.raises(ScenarioError) as in_process:
        run(sc)
    with pytest.raises(ScenarioError) as streamed:
        run_streamed(sc)
    assert str(streamed.value) == str(in_process.value)
    assert "did not finish" in str(streamed.value)


def test_a_drive_worker_killed_mid_drive_is_a_clear_error_and_no_orphan(monkeypatch):
    started = []

    class Watched(DriveWorker):
        def parts(self):
            for part in super().parts():
                if not started:  # killed once it has driven a part, and gone before the next is read
                    started.append(self.proc)
                    os.kill(self.proc.pid, signal.SIGKILL)
                    self.proc.wait()
                yield part

    monkeypatch.setattr("services.sim.streamed.DriveWorker", Watched)
    with pytest.raises(RuntimeError, match=r"drive worker .* ended before the drive did \(exit code -9\)"):
        run_streamed(load("default"))
    assert started[0].poll() == -9


def _drive_workers(mark: bytes) -> set[int]:
    """Drive workers whose environment carries `mark`: started by this test's command (other runs on
    the machine, a parallel test's or a developer's, are not this test's business)."""
    found = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                if b"services.sim.drive_worker" not in fh.read():
                    continue
            with open(f"/proc/{pid}/environ", "rb") as fh:
                if mark in fh.read().split(b"\0"):
                    found.add(int(pid))
        except OSError:
            pass
    return found


@pytest.mark.parametrize("args, code, says", [
    (["no_such_scenario.toml"], 2, "no such scenario file"),
    (["default", "--set", "tractor.working_speed_m_s=-1"], 2, "working_speed_m_s"),
    (["default", "--check"], 0, "Machine check"),
])
def test_vrsim_run_that_stops_early_leaves_no_drive_worker(args, code, says):
    import subprocess
    import uuid

    from tests.conftest import VRSIM

    mark = f"VRSIM_TEST_MARK={uuid.uuid4().hex}"
    env = dict(os.environ, VRSIM_TEST_MARK=mark.split("=", 1)[1])
    done = subprocess.run([VRSIM, "run", *args], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == code, done.stderr
    assert says in done.stdout + done.stderr and "Traceback" not in done.stderr
    assert _drive_workers(mark.encode()) == set()
