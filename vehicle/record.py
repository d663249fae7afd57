"""The per-tick vehicle record: true and measured position (local and WGS84), heading, speed, sections.

`vehicle_record` turns a `SumoDriver.run_all` track into the arrays the run loop stores, adding the
GNSS fix and the speed-sensor reading the controller sees.
"""

from __future__ import annotations

import numpy as np

from vehicle.field import Field
from vehicle.gnss import Gnss
from vehicle.speed_sensor import SpeedSensor

KEYS = ("time_s", "x_m", "y_m", "lon_deg", "lat_deg", "x_meas_m", "y_meas_m", "lon_meas_deg",
        "lat_meas_deg", "heading_rad", "speed_m_s", "speed_meas_m_s", "implement_on")


def vehicle_record(field: Field, track: dict, gnss: Gnss, speed_sensor: SpeedSensor | None = None) -> dict:
    """Per-tick record of a driven track.

    Parameters
    ----------
    field : Field
        Gives the CRS for the WGS84 columns.
    track : dict of ndarray, shape (n,)
        `SumoDriver.run_all` output (``time_s``, ``x_m``, ``y_m``, ``heading_rad``, ``speed_m_s``,
        ``implement_on``).
    gnss : Gnss
        Measures the positions (its track is restarted).
    speed_sensor : SpeedSensor, optional
        Measures the speed; default: the true speed.

    Returns
    -------
    dict of ndarray, shape (n,), keyed by `KEYS` (degrees for lon/lat, math-convention heading).
    """
    t, x, y = track["time_s"], track["x_m"], track["y_m"]
    xm, ym = gnss.measure(t, x, y)
    lon, lat = field.to_wgs84(x, y)
    lon_m, lat_m = field.to_wgs84(xm, ym)
    v = track["speed_m_s"]
    v_meas = speed_sensor.measure(t, v) if speed_sensor is not None else np.array(v, dtype=float)
    return {"time_s": t, "x_m": x, "y_m": y, "lon_deg": np.asarray(lon), "lat_deg": np.asarray(lat),
            "x_meas_m": xm, "y_meas_m": ym, "lon_meas_deg": np.asarray(lon_m),
            "lat_meas_deg": np.asarray(lat_m), "heading_rad": track["heading_rad"], "speed_m_s": v,
            "speed_meas_m_s": v_meas, "implement_on": track["implement_on"]}
