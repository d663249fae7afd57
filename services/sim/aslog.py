"""The as-applied log of a run: what a task controller would have logged, as a `maps.PointLog`.

One record per control tick, thinned to ``[output] log_rate_hz`` (the first tick of every period):

- time: the run's start plus the simulated time;
- position, heading and speed: the implement's true ones on the path (the simulation knows them;
  the position status is ISO 11783's 8, "simulate mode"), heading in degrees clockwise from north;
- target: the setpoint the controller worked to (the prescription at the predicted landing point);
- applied: the actual rate of the tick, its metered product over the strip it lands on
  (`services.sim.landing.applied_rate_kg_ha`); 0 with every section off, NaN (not logged) at a
  standstill with sections on;
- working width and section states: the gates that were open, per section, as section control
  switched them (the control core's ``sections_on``; DDI 161, condensed work states, in the TimeLog).

The applied rate of a record is metered at the record's time and lands ``delivery_delay_s`` later,
where the implement is then: `services.sim.evaluate` compares it with the prescription there when
given ``delay_s``.
"""

from __future__ import annotations

import numpy as np

from vrsim.maps import PointLog

SIMULATE_MODE = 8  # ISO 11783 position status "simulate mode"


def _compass_deg(heading_rad) -> np.ndarray:
    """Heading in degrees clockwise from north, [0, 360), from radians counter-clockwise from east."""
    return np.mod(90.0 - np.degrees(np.asarray(heading_rad, dtype=float)), 360.0)


def run_point_log(world, track: dict, control: dict, applied_kg_ha, started_unix: float,
                  rate_hz: float) -> PointLog:
    """The run's as-applied log at `rate_hz` records per second, its rates in the map's own unit.

    Parameters
    ----------
    world : services.sim.world.World
        The run's world (its field's CRS and the implement).
    track, control : dict
        The run's true track and control-core arrays (``width_on_m`` per tick, ``sections_on`` per tick
        and section).
    applied_kg_ha : ndarray, shape (n,)
        The applied rate per tick (`services.sim.landing.Landing.applied_kg_ha`).
    started_unix : float
        When the run started (Unix time): the log's absolute times start there.
    rate_hz : float
        Records per second.
    """
    width_on = np.asarray(control["width_on_m"], dtype=float)
    log = PointLog(
        track["x_m"], track["y_m"], world.field.crs, applied=np.where(width_on > 0, applied_kg_ha, 0.0),
        target=control["prescribed_kg_ha"], unit="kg/ha", time_s=track["time_s"],
        start=np.datetime64(round(started_unix * 1000.0), "ms"),
        heading_deg=_compass_deg(track["heading_rad"]),
        speed_m_s=track["speed_m_s"], width_m=width_on, work_on=np.asarray(track["implement_on"], bool),
        sections_on=np.asarray(control["sections_on"], bool), gnss_status=SIMULATE_MODE,
        source=world.scenario.name, format="run")
    grid = world.grid
    return log.thin(1.0 / rate_hz).in_unit(grid.map_unit, grid.density_kg_l, grid.seed_mass_g)
