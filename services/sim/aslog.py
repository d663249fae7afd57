"""The as-applied log of a run: what a task controller would have logged, as a `maps.PointLog`.

One record per control tick, thinned to ``[output] log_rate_hz`` (the first tick of every period):

- time: the run's start plus the simulated time;
- position, heading and speed: the implement's true ones on the path (the simulation knows them;
  the position status is ISO 11783's 8, "simulate mode"), heading in degrees clockwise from north;
- target: the setpoint the controller worked to (the prescription at the predicted landing point);
- applied: the actual rate of the tick, its metered product over the strip it lands on
  (`services.sim.landing.applied_rate_kg_ha`); 0 with every section off, NaN (not logged) at a
  standstill with sections on;
- working width and section states: the sections that were on (`section_states`).

The applied rate of a record is metered at the record's time and lands ``delivery_delay_s`` later,
where the implement is then: `services.sim.evaluate` compares it with the prescription there when
given ``delay_s``.
"""

from __future__ import annotations

import numpy as np

from maps import PointLog
from vehicle import Implement

SIMULATE_MODE = 8  # ISO 11783 position status "simulate mode"


def section_states(implement: Implement, width_on_m, offset_m) -> np.ndarray:
    """Per-section on/off, shape (n, sections), section 1 the leftmost, from the control core's width
    on and its centre's offset to the left, per tick.

    The core switches the sections that are on as one strip (see `ControlCore.sections`): a section is
    on when its centre lies within that strip. (#12's coverage-based section control can hand the
    states themselves instead.)
    """
    half = 0.5 * np.asarray(width_on_m, dtype=float)[:, None]
    centre = np.asarray(offset_m, dtype=float)[:, None]
    return np.abs(implement.section_offsets_m[None, :] - centre) < half


def compass_deg(heading_rad) -> np.ndarray:
    """Heading in degrees clockwise from north, [0, 360), from radians counter-clockwise from east."""
    return np.mod(90.0 - np.degrees(np.asarray(heading_rad, dtype=float)), 360.0)


def run_point_log(world, track: dict, control: dict, applied_kg_ha, started_unix: float,
                  rate_hz: float) -> PointLog:
    """The run's as-applied log at `rate_hz` records per second.

    Parameters
    ----------
    world : services.sim.world.World
        The run's world (its field's CRS and the implement).
    track, control : dict
        The run's true track and control-core arrays (``width_on_m`` and ``offset_m`` per tick).
    applied_kg_ha : ndarray, shape (n,)
        The applied rate per tick (`services.sim.landing.Landing.applied_kg_ha`).
    started_unix : float
        When the run started (Unix time): the log's absolute times start there.
    rate_hz : float
        Records per second.
    """
    implement = world.scenario.implement
    width_on = np.asarray(control["width_on_m"], dtype=float)
    log = PointLog(
        track["x_m"], track["y_m"], world.field.crs, applied=np.where(width_on > 0, applied_kg_ha, 0.0),
        target=control["prescribed_kg_ha"], unit="kg/ha", time_s=track["time_s"],
        start=np.datetime64(round(started_unix * 1000.0), "ms"),
        heading_deg=compass_deg(track["heading_rad"]),
        speed_m_s=track["speed_m_s"], width_m=width_on, work_on=np.asarray(track["implement_on"], bool),
        sections_on=section_states(implement, width_on, control["offset_m"]), gnss_status=SIMULATE_MODE,
        source=world.scenario.name, format="run")
    return log.thin(1.0 / rate_hz)
