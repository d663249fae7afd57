"""`run` on two cores: SUMO drives in a second process while this one measures and controls the part
of the track driven so far (what `vrsim run` does).

libsumo holds the GIL while it steps, and stepping is about half of a run, so a thread would not
help; a process does. Nothing that follows SUMO feeds back into it (the tractor's path does not
depend on the metering), and everything that follows goes part by part with its state carried:
the track (`vehicle.track_on_path`), the sensors (`Gnss.measure_next`, `SpeedSensor.measure_next`)
and the control core (`ControlCore.run_track`, which the controller service calls per lockstep
batch, and whose result does not depend on how a track is split: tested). A streamed run's arrays
and summary equal `services.sim.run.run`'s bit for bit; only the wall times differ.

This process plans the path and sends it to the second (`services.sim.drive_worker`) before it
builds the rest of the world (the prescription). With ``error_split``, the error split's reference meters
(`services.sim.error_split.reference_figures`) land in a forked child while this process accounts
for the run.
"""

from __future__ import annotations

import time

import numpy as np

from common.forked import Forked
from services.sim.accounting import StageTimer
from services.sim.core import ControlCore
from services.sim.drive_worker import PART_TICKS, DriveWorker
from services.sim.error_split import reference_figures
from services.sim.run import RunResult, accounted, sensors
from services.sim.scenario import Scenario
from services.sim.world import build_world
from vehicle import track_on_path


def run_streamed(scenario: Scenario, progress=None, worker: DriveWorker | None = None,
                 ticks_per_part: int = PART_TICKS, error_split: bool = False) -> RunResult:
    """`services.sim.run.run` of `scenario`, SUMO driving in a second process (see the module
    docstring): the same result, sooner on two cores.

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
        report shows), in a forked child beside the accounting.

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
        core = ControlCore(world.grid, scenario, world.field.polygon, world.path)
        gnss, speed = sensors(scenario)
        period_s = scenario.timing.control_period_s
        expected = world.path.length_m / (scenario.tractor.working_speed_m_s * period_s)
        tracks, measured, controls, done = [], [], [], 0
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
                controls.append(core.run_track(x_m, y_m, track["heading_rad"], v_m_s, track["implement_on"],
                                               track["s_m"], part_progress))
            tracks.append(track)
            measured.append((x_m, y_m, v_m_s))
            done += len(time_s)
            clock = time.perf_counter()
        timer.add("wait_s", time.perf_counter() - clock)
    finally:
        worker.close()
    timer.add("sumo_s", worker.sumo_s)
    track, control = _joined(tracks), _joined(controls)
    measured = tuple(np.concatenate(m) for m in zip(*measured, strict=True))
    if not error_split:
        return accounted(world, track, measured, control, timer, started)
    # The error split's reference meters need the drive and the control only: a forked child lands
    # them on the other core while this one accounts for the run.
    with Forked(reference_figures, world, track, control, measured[2]) as references:
        result = accounted(world, track, measured, control, timer, started)
        result.reference_figures = references.result()
    return result


def _joined(parts: list[dict]) -> dict:
    """Per-tick arrays of consecutive parts, joined along the ticks."""
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
