"""`run` on two cores: SUMO drives in a second process while this one measures and controls the part
of the track driven so far (what `vrsim run` does).

libsumo holds the GIL while it steps, and stepping is about half of a run, so a thread would not
help; a process does. Nothing that follows SUMO feeds back into it (the tractor's path does not
depend on the metering), and everything that follows goes part by part with its state carried:
the track (`vehicle.track_on_path`), the sensors (`Gnss.measure_next`, `SpeedSensor.measure_next`)
and the control core (`ControlCore.run_track`, which the controller service calls per lockstep
batch, and whose result does not depend on how a track is split: tested) and the accounting
(`services.sim.bounded`: each part is landed and deposited as it comes, and only what the outputs
need is kept). A streamed run's summary and rasters equal `services.sim.run.run`'s bit for bit; only
the wall times differ; it keeps no per-tick arrays (the track goes to a sink as it is accounted).

This process plans the path and sends it to the second (`services.sim.drive_worker`) before it
builds the rest of the world (the prescription). With ``error_split``, the error split's reference meters
are deposited beside the run's own (their figures equal the in-process run's to rounding).
"""

from __future__ import annotations

import time

from vrsim.services.sim.accounting import StageTimer
from vrsim.services.sim.bounded import BoundedAccount
from vrsim.services.sim.drive_worker import PART_TICKS, DriveWorker
from vrsim.services.sim.run import RunResult, start_up
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.world import build_world
from vrsim.vehicle import track_on_path


def run_streamed(scenario: Scenario, progress=None, worker: DriveWorker | None = None,
                 ticks_per_part: int = PART_TICKS, error_split: bool = False, track_sink=None,
                 on_world=None) -> RunResult:
    """`services.sim.run.run` of `scenario`, SUMO driving in a second process and each part accounted
    as it comes (see the module docstring): the same figures, sooner on two cores, in memory set by the
    map and one part (`services.sim.bounded`; the result keeps no per-tick arrays: ``result.bounded``).

    Parameters
    ----------
    scenario : Scenario
    progress : callable, optional
        As `services.sim.run.run`'s (the total is the path's ticks at the working speed until the
        drive ends).
    worker : DriveWorker, optional
        Started (`vrsim run` starts it first, so that SUMO's process imports while this one does), and
        perhaps already driving `scenario`; closed here. None: one is started now.
    ticks_per_part : int
        Without `worker`: how many ticks SUMO drives before it sends them (`PART_TICKS`; any size
        gives the same result).
    error_split : bool
        Also compute the error split's reference figures (``result.reference_figures``, which the
        report shows), deposited beside the run's own.
    track_sink : callable, optional
        Given each accounted stretch's per-tick rows (`services.sim.bounded.BoundedAccount`): the track
        files, written as they go.
    on_world : callable, optional
        Given the run's world (`services.sim.world.World`) once it is built, before the first rows.

    ``stage_s`` holds this process's ``build_s``, ``sensors_s``, ``control_s`` and ``metrics_s``, the
    worker's ``sumo_s`` and ``wait_s``, the time this process waited for SUMO's parts: the stages
    overlap, so they do not add up to ``wall_time_s``.
    """
    worker = worker or DriveWorker()
    started = worker.started_unix
    # The run began with SUMO's process; the stages in the summary's order, the worker's last.
    timer = StageTimer(dict.fromkeys(("build_s", "sensors_s", "control_s", "wait_s"), 0.0),
                       started_s=worker.started_perf_s)
    try:
        if worker.planned is None:
            worker.drive(scenario, ticks_per_part)
        with timer.stage("build_s"):
            world = build_world(scenario, planned=worker.planned)
        timer.add("build_s", worker.plan_s)
        scenario = world.scenario   # as run: what the control, the sensors and the outputs use
        if on_world is not None:
            on_world(world)
        core, gnss, speed = start_up(world)
        period_s = scenario.timing.control_period_s
        expected = world.path.length_m / (scenario.tractor.working_speed_m_s * period_s)
        account = BoundedAccount(world, timer, started, expected, track_sink, references=error_split)
        done = 0
        clock = time.perf_counter()
        for time_s, s_m, speed_m_s in worker.parts():
            timer.add("wait_s", time.perf_counter() - clock)
            with timer.stage("sensors_s"):
                track = track_on_path(world.path, time_s, s_m, speed_m_s)
                x_m, y_m = gnss.measure_next(track["time_s"], track["x_m"], track["y_m"])
                v_m_s = speed.measure_next(track["time_s"], track["speed_m_s"])
            part_progress = None if progress is None else \
                (lambda n, _, before=done: progress(before + n, max(expected, before + n)))
            with timer.stage("control_s"):
                control = core.run_track(x_m, y_m, track["heading_rad"], v_m_s, track["implement_on"],
                                         track["s_m"], part_progress)
            account.add(track, v_m_s, control)
            done += len(time_s)
            clock = time.perf_counter()
        timer.add("wait_s", time.perf_counter() - clock)
    finally:
        worker.close()
    timer.add("sumo_s", worker.sumo_s)
    return account.result()
