"""track.csv: one row per tick (time, position, speed, shaft, current, rates, sections)."""

from __future__ import annotations

import io

import numpy as np

from services.sim.run import RunResult
from services.sim.sections import section_masks

TRACK_COLUMNS = ("time_s", "lat", "lon", "speed_m_s", "target_shaft_rpm", "shaft_rpm", "current_a",
                 "prescribed_kg_ha", "applied_kg_ha", "implement_on", "sections_on", "section_mask")


def write_track_csv(result: RunResult, path: str) -> None:
    """``sections_on`` counts the sections whose gates are open in the tick, ``section_mask`` says which
    (hexadecimal bitmask, bit k the k-th section from the left: `services.sim.sections.section_masks`)."""
    track, control, landing = result.track, result.control, result.landing
    lon, lat = result.world.field.to_wgs84(track["x_m"], track["y_m"])
    gates = control["sections_on"]
    columns = np.column_stack([track["time_s"], lat, lon, track["speed_m_s"], control["target_shaft_rpm"],
                               control["shaft_rpm"], control["current_a"], landing.prescribed_kg_ha,
                               landing.applied_kg_ha, np.asarray(track["implement_on"], float),
                               gates.sum(axis=1)])
    fmt = ["%.3f", "%.8f", "%.8f", "%.3f", "%.3f", "%.3f", "%.5f", "%.2f", "%.2f", "%d", "%d"]
    numbers = io.StringIO()
    np.savetxt(numbers, columns, fmt=fmt, delimiter=",")
    rows = numbers.getvalue().splitlines()
    with open(path, "w") as fh:
        fh.write(",".join(TRACK_COLUMNS) + "\n")
        fh.writelines(f"{row},{mask}\n" for row, mask in zip(rows, section_masks(gates), strict=True))
