"""The streamed run (`services.sim.streamed`, what `vrsim run` does): SUMO in a second process, the
track measured, controlled and accounted part by part (`services.sim.bounded`), equal to the in-process
run bit for bit (real SUMO)."""

import os
import signal

import numpy as np
import pytest

from vrsim.common import ScenarioError
from vrsim.maps.pointlog import COLUMNS
from vrsim.services.outputs.encode import dumps
from vrsim.services.outputs.track import track_rows
from vrsim.services.sim.run import run
from vrsim.services.sim.scenario import load, with_changes
from vrsim.services.sim.streamed import DriveWorker, run_streamed

pytestmark = pytest.mark.integration

CLOCK_KEYS = {"wall_time_s", "realtime_factor", "stage_s"}
QUICK = "scenarios/quick_rectangle.toml"


def assert_same_run(whole, bounded, rows: list[dict]):
    """The in-process run `whole` and the streamed, bounded run (the track `rows` its sink got): the same
    figures, rasters, track, pictures' data and as-applied log, bit for bit."""
    assert bounded.bounded and bounded.track is None and not whole.bounded
    assert dumps({k: v for k, v in whole.summary.items() if k not in CLOCK_KEYS}) == \
        dumps({k: v for k, v in bounded.summary.items() if k not in CLOCK_KEYS})  # NaN as null: equal
    for name in ("applied_kg_ha", "coverage_fraction", "overlap_fraction", "overlap_kg", "pass_count"):
        assert np.array_equal(getattr(whole.as_applied, name), getattr(bounded.as_applied, name),
                              equal_nan=True), name
    for name in ("worked_fraction", "limited_fraction", "in_field"):
        assert np.array_equal(getattr(whole, name), getattr(bounded, name)), name
    track = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    for key, values in track_rows(whole).items():
        assert np.array_equal(values, track[key], equal_nan=True), key
    a, b = whole.kept, bounded.kept
    assert all(np.array_equal(x, y) for x, y in zip(a.path_xy, b.path_xy, strict=True))
    assert all(np.array_equal(a.series[k], b.series[k], equal_nan=True) for k in a.series)
    for name in COLUMNS:
        assert np.array_equal(getattr(a.point_log, name), getattr(b.point_log, name), equal_nan=True), name


@pytest.fixture(scope="module")
def quick_whole():
    """The quick scenario's in-process run: one run for the tests that compare against it unchanged."""
    return run(load(QUICK))


@pytest.mark.parametrize("changes", [
    {},
    # coverage section control remembers where product landed; the look-ahead tune re-looks ticks up
    {"implement": {"sections": 5, "section_control": "coverage"},
     "controller": {"kind": "smith", "look_ahead_s": "auto", "look_ahead_tune": 0.5},
     "gnss": {"kind": "dgps"}},
])
def test_in_parts_of_any_size_the_run_is_the_in_process_run(changes, request):
    sc = with_changes(load(QUICK), **changes)
    whole = run(sc) if changes else request.getfixturevalue("quick_whole")
    ticks = len(whole.track["time_s"])
    # parts far smaller than the control core's chunks, and one not dividing them
    rows = []
    streamed = run_streamed(sc, ticks_per_part=3001, track_sink=rows.append)
    assert ticks > 4 * 3001
    assert_same_run(whole, streamed, rows)
    stage = streamed.summary["stage_s"]
    assert stage["sumo_s"] > 0 and stage["wait_s"] >= 0 and stage["control_s"] > 0


@pytest.mark.slow
def test_the_bounded_run_of_the_default_scenario_is_the_in_process_run_bit_for_bit():
    sc = load("default")
    rows = []
    assert_same_run(run(sc), run_streamed(sc, track_sink=rows.append), rows)


def test_in_parts_a_drive_per_section_runs_as_in_process():
    """``section_drives``: each drive's held rate and loop carried over, the tune re-looking ticks up.
    Several loops advance on the PID's shared lifted path, whose calls carry on from the last one's
    last product: the parts give the whole run's numbers bit for bit."""
    sc = with_changes(load(QUICK), implement={"kind": "section_drives"}, map={"policy": "hold"},
                      controller={"kind": "PID", "look_ahead_tune": 0.5})
    rows = []
    assert_same_run(run(sc), run_streamed(sc, ticks_per_part=3001, track_sink=rows.append), rows)


def test_the_error_split_computed_beside_the_accounting_is_the_one_computed_after_it(quick_whole):
    from vrsim.services.sim.error_split import error_split

    streamed = run_streamed(load(QUICK), error_split=True)
    assert streamed.reference_figures is not None
    whole = quick_whole
    assert whole.reference_figures is None
    # The reference meters' product is summed part by part, per cell and in single precision, their swept
    # area in single precision (`maps.meter_totals`): to a few parts in a million (shown: two decimals).
    for a, b in zip(error_split(streamed), error_split(whole), strict=True):
        assert a.cause == b.cause
        assert (a.mass_balance_pct, a.mae_kg_ha, a.share_pct) == pytest.approx(
            (b.mass_balance_pct, b.mae_kg_ha, b.share_pct), rel=1e-5, abs=1e-6)


def test_progress_counts_every_tick_once():
    seen = []
    sc = load(QUICK)
    result = run_streamed(sc, progress=lambda done, total: seen.append((done, total)), ticks_per_part=5000)
    done = [d for d, _ in seen]
    assert done == sorted(done) and done[-1] == result.summary["ticks"]
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

    monkeypatch.setattr("vrsim.services.sim.streamed.DriveWorker", Watched)
    with pytest.raises(RuntimeError, match=r"drive worker .* ended before the drive did \(exit code -9\)"):
        run_streamed(load("default"))
    assert started[0].poll() == -9


def test_sumo_may_drive_parts_ahead_of_the_run():
    """SUMO's pipe holds several parts (`PIPE_BYTES`), where the system allows it: SUMO does not wait
    on each part's write while the run accounts a slow one."""
    import fcntl

    from vrsim.services.sim.drive_worker import PART_TICKS, PIPE_BYTES

    worker = DriveWorker()
    try:
        held_bytes = fcntl.fcntl(worker.proc.stdout.fileno(), fcntl.F_GETPIPE_SZ)
    finally:
        worker.close()
    with open("/proc/sys/fs/pipe-max-size") as fh:
        allowed_bytes = int(fh.read())
    part_bytes = 3 * 8 * PART_TICKS   # time, distance along the path and speed, float64
    assert PIPE_BYTES >= 8 * part_bytes
    assert held_bytes >= (PIPE_BYTES if PIPE_BYTES <= allowed_bytes else 1 << 16)


class _FullPipe:
    """The worker's stdout as a pipe that is always full: each write waits `WAIT_S` for room, on the
    worker's clock (`_InjectedClock`), then keeps the bytes."""

    WAIT_S = 1000.0

    def __init__(self, clock):
        self.clock, self.data, self.writes = clock, bytearray(), 0

    def write(self, data) -> int:
        self.clock.offset_s += self.WAIT_S
        self.writes += 1
        self.data += data
        return len(data)

    def flush(self) -> None:
        pass


class _InjectedClock:
    """`time` for the drive worker: real time plus what the `_FullPipe` made it wait."""

    def __init__(self):
        import time

        self.offset_s, self._real = 0.0, time.perf_counter

    def perf_counter(self) -> float:
        return self._real() + self.offset_s


def test_sumo_s_is_sumos_time_not_the_time_its_parts_waited_for_the_run(monkeypatch):
    """A run that accounts slowly keeps SUMO waiting on a full pipe: that wait is the run's, and
    ``stage_s["sumo_s"]`` says how long SUMO took to drive. The worker drives here (in this process,
    reading its job from bytes) into a pipe where every write waits 1000 s on its clock."""
    import io
    import pickle

    from vrsim.services.sim import drive_worker
    from vrsim.services.sim.drive_job import DriveJob
    from vrsim.services.sim.world import plan_path

    sc = load(QUICK)
    job = pickle.dumps((DriveJob.of(sc, plan_path(sc)[1]), 500), protocol=pickle.HIGHEST_PROTOCOL)
    clock = _InjectedClock()
    out = _FullPipe(clock)
    monkeypatch.setattr(drive_worker, "time", clock)
    drive_worker._serve(io.BytesIO(job), out)
    stream = io.BytesIO(bytes(out.data))
    messages = []
    while stream.tell() < len(out.data):
        messages.append(pickle.load(stream))
    kinds = [m[0] for m in messages]
    assert kinds[-1] == "done" and kinds.count("part") == len(kinds) - 1 >= 3, kinds
    (_, sumo_s) = messages[-1]
    print(f"sumo_s {sumo_s:.2f} s; the parts' writes waited {out.writes * _FullPipe.WAIT_S:,.0f} s")
    assert out.writes >= len(kinds)
    assert 0 < sumo_s < _FullPipe.WAIT_S  # none of the waiting for room counts as SUMO's


def test_handing_sumo_its_job_does_not_wait_for_sumo_to_read_it():
    """The job is more than a pipe holds and SUMO reads it once libsumo is imported: `drive` returns
    at once (the run builds its world meanwhile), and SUMO gets the job whole when it reads."""
    import fcntl
    import pickle
    import threading

    from vrsim.services.sim.drive_job import DriveJob
    from vrsim.services.sim.drive_worker import PART_TICKS
    from vrsim.services.sim.world import plan_path

    sc = load("default")
    job_bytes = len(pickle.dumps(DriveJob.of(sc, plan_path(sc)[1]), protocol=pickle.HIGHEST_PROTOCOL))
    worker = DriveWorker()
    try:
        assert job_bytes > fcntl.fcntl(worker.proc.stdin.fileno(), fcntl.F_GETPIPE_SZ)
        os.kill(worker.proc.pid, signal.SIGSTOP)   # a worker that reads nothing yet
        handing = threading.Thread(target=worker.drive, args=(sc,))
        handing.start()
        handing.join(timeout=30.0)
        assert not handing.is_alive()
        os.kill(worker.proc.pid, signal.SIGCONT)
        time_s, _, _ = next(worker.parts())   # the job arrived whole: SUMO drives it
        assert len(time_s) == PART_TICKS
    finally:
        os.kill(worker.proc.pid, signal.SIGCONT)
        worker.close()


def _drive_workers(mark: bytes) -> set[int]:
    """Drive workers whose environment carries `mark`: started by this test's command (other runs on
    the machine, a parallel test's or a developer's, are not this test's business)."""
    found = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                if b"vrsim.services.sim.drive_worker" not in fh.read():
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


def test_timeseries_drawn_as_the_run_goes_is_the_one_drawn_after_it(tmp_path):
    from vrsim.services.outputs import plots
    from vrsim.services.outputs.early import EarlyTimeseries
    from vrsim.services.outputs.plot_worker import PlotWorker

    worker = PlotWorker().start()
    early = EarlyTimeseries(worker)
    try:
        # Zones: a rate step early in the run (a smooth map has none: its minute is the run's first, known
        # only at the end, when no step came).
        zones = with_changes(load(QUICK), map={"synthetic": "zones", "params": {"n_zones": 5}})
        result = run_streamed(zones, ticks_per_part=500, track_sink=early, on_world=early.world_built)
        assert early.submitted   # its minute was whole before the run's end
        png = worker.result()
    finally:
        worker.close()
    plots.draw_timeseries(plots.series_picture(result), str(tmp_path / "timeseries.png"))
    assert png == (tmp_path / "timeseries.png").read_bytes()
