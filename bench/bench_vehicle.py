"""Vehicle costs: one SUMO tick with the pose read, and planning + network build for 50 ha.

Figures
-------
sumo_tick_us        run_all() over the default ~20 ha field (12 m, 2.5 m/s, 50 ms ticks), per tick
step_tick_us        the same drive with step() (one Pose object per tick), per tick
run_all_20ha_s      the whole 20 ha drive with run_all(), s
path_build_50ha_s   plan_coverage + netconvert network for a 50 ha field, uncached, s
gnss_measure_20ha_ms  Gnss.measure over the 20 ha track (RTK), ms
"""

from __future__ import annotations

import tempfile
import time

from vrsim.vehicle import DriveConfig, Field, Gnss, GnssConfig, SumoDriver, build_network, plan_coverage


def run() -> dict[str, float]:
    drive = DriveConfig()
    with tempfile.TemporaryDirectory(prefix="vrsim-bench-") as cache:
        field_50 = Field.rectangle(625.0, 800.0)
        t0 = time.perf_counter()
        path_50 = plan_coverage(field_50, 12.0)
        build_network(path_50.segments, drive.edge_speeds_m_s(path_50.kinds()), 20.0, cache_dir=cache)
        path_build_50 = time.perf_counter() - t0

        path = plan_coverage(Field.rectangle(400.0, 500.0), 12.0)
        with SumoDriver(path, drive, step_s=0.05, seed=1, cache_dir=cache) as drv:
            t0 = time.perf_counter()
            track = drv.run_all()
            run_all_s = time.perf_counter() - t0
        ticks = len(track["time_s"])
        with SumoDriver(path, drive, step_s=0.05, seed=1, cache_dir=cache) as drv:
            t0 = time.perf_counter()
            while not drv.finished:
                drv.step()
            step_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        Gnss(GnssConfig("rtk"), seed=1).measure(track["time_s"], track["x_m"], track["y_m"])
        gnss_s = time.perf_counter() - t0
    return {
        "sumo_tick_us": run_all_s / ticks * 1e6,
        "step_tick_us": step_s / ticks * 1e6,
        "run_all_20ha_s": run_all_s,
        "path_build_50ha_s": path_build_50,
        "gnss_measure_20ha_ms": gnss_s * 1e3,
    }


if __name__ == "__main__":
    for name, value in run().items():
        print(f"{name:<24} {value:10.3f}")
