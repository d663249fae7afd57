"""What a coarser SUMO step costs in position and saves in time, over the accuracy library.

Each scenario of tests/accuracy/scenarios is driven twice on its planned path: SUMO at the control
period (the reference, 50 ms in every scenario) and SUMO at ``[timing] sumo_step_s`` = 2 control
periods, the ticks between its steps interpolated along the path (`vehicle.SumoDriver`). Positions
are compared tick by tick over the ticks both drives have (the same times, bit for bit).

Figures
-------
sumo_interp_max_position_error_m   largest distance between a tick's position in the two drives,
                                   over every tick of every scenario, m (the model's bound: 0.01 m)
sumo_interp_drive_time_ratio       the coarser drives' SUMO time over the reference drives', summed

    .venv/bin/python -m bench.bench_sumo_step
"""

from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from vrsim.services.sim import accuracy, scenario
from vrsim.services.sim.drive_job import DriveJob
from vrsim.services.sim.world import plan_path
from vrsim.vehicle import track_on_path

STEP_RATIO = 2  # SUMO's step in control periods: 100 ms at the library's 50 ms


def _drive(job: DriveJob) -> tuple[dict, float]:
    """The track of `job` and SUMO's wall time for it, s."""
    with job.driving() as driver:
        t0 = time.perf_counter()
        parts = list(driver.run_parts(4000))
        wall_s = time.perf_counter() - t0
    time_s, s_m, speed_m_s = (np.concatenate([p[k] for p in parts]) for k in range(3))
    return track_on_path(job.path, time_s, s_m, speed_m_s), wall_s


def position_error_m(name: str, ratio: int = STEP_RATIO) -> tuple[float, float, float]:
    """(largest position difference in m, reference SUMO s, coarser SUMO s) of library scenario `name`."""
    sc = scenario.load(os.path.join(accuracy.SCENARIO_DIR, name + ".toml"))
    reference = DriveJob.of(sc, plan_path(sc)[1])
    period = sc.timing.control_period_s
    coarser = dataclasses.replace(reference, step_s=ratio * period, tick_s=period)
    (ref, ref_s), (got, got_s) = _drive(reference), _drive(coarser)
    n = min(len(ref["time_s"]), len(got["time_s"]))
    if not np.array_equal(ref["time_s"][:n], got["time_s"][:n]):
        raise AssertionError(f"{name}: the interpolated ticks are not the reference's times")
    error = np.hypot(ref["x_m"][:n] - got["x_m"][:n], ref["y_m"][:n] - got["y_m"][:n])
    return float(error.max()), ref_s, got_s


def run() -> dict[str, float]:
    worst, ref_total, got_total = 0.0, 0.0, 0.0
    for name in accuracy.scenario_names():
        error_m, ref_s, got_s = position_error_m(name)
        print(f"  {name:<40} {error_m:.4f} m")
        worst, ref_total, got_total = max(worst, error_m), ref_total + ref_s, got_total + got_s
    return {"sumo_interp_max_position_error_m": worst, "sumo_interp_drive_time_ratio": got_total / ref_total}


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:<36} {value:,.4g}")
