"""track.csv: one row per tick (time, position, speed, shaft, current, rates, sections)."""

from __future__ import annotations

import numpy as np

from services.sim.run import RunResult

TRACK_COLUMNS = ("time_s", "lat", "lon", "speed_m_s", "target_shaft_rpm", "shaft_rpm", "current_a",
                 "prescribed_kg_ha", "applied_kg_ha", "implement_on")


def write_track_csv(result: RunResult, path: str) -> None:
    track, control, landing = result.track, result.control, result.landing
    lon, lat = result.world.field.to_wgs84(track["x_m"], track["y_m"])
    columns = np.column_stack([track["time_s"], lat, lon, track["speed_m_s"], control["target_shaft_rpm"],
                               control["shaft_rpm"], control["current_a"], landing.prescribed_kg_ha,
                               landing.applied_kg_ha, np.asarray(track["implement_on"], float)])
    fmt = ["%.3f", "%.8f", "%.8f", "%.3f", "%.3f", "%.3f", "%.5f", "%.2f", "%.2f", "%d"]
    np.savetxt(path, columns, fmt=fmt, delimiter=",", header=",".join(TRACK_COLUMNS), comments="")
