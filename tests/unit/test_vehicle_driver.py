"""Pure parts of driving: configuration, speed variation, speed sensor (no SUMO here)."""

import numpy as np
import pytest

from vrsim.common.errors import VehicleError
from vrsim.vehicle import (
    DriveConfig,
    SpeedSensor,
    SpeedSensorConfig,
    SpeedVariation,
)


def test_drive_config_defaults_and_edge_speeds():
    d = DriveConfig()
    assert d.max_speed_m_s == pytest.approx(2.5 * 1.05)
    assert d.edge_speeds_m_s(["headland", "turn", "swath"]) == [d.max_speed_m_s, 1.2, d.max_speed_m_s]
    slow = DriveConfig(headland_speed_m_s=1.8)
    assert slow.edge_speeds_m_s(["headland", "turn", "swath"]) == [1.8, 1.2, slow.max_speed_m_s]


@pytest.mark.parametrize("kwargs, match", [
    (dict(working_speed_m_s=0), "working_speed_m_s must be a number > 0"),
    (dict(turn_speed_m_s=-1), "turn_speed_m_s"),
    (dict(headland_speed_m_s=0.0), "headland_speed_m_s"),
    (dict(accel_m_s2=float("nan")), "accel_m_s2"),
    (dict(speed_variation_pct=-1), "speed_variation_pct"),
    (dict(speed_variation_pct=80), "speed_variation_pct"),
    (dict(implement_offset_m=3.0), "implement_offset_m=3.0 must be >= vehicle_length_m"),
    (dict(working_speed_m_s=30.0), "not a field speed"),
])
def test_drive_config_validation(kwargs, match):
    with pytest.raises(VehicleError, match=match):
        DriveConfig(**kwargs)


def test_speed_variation_is_seeded_slow_and_bounded():
    a = [SpeedVariation(5.0, 20.0, 1.0, seed=1).next() for _ in range(1)]
    v = SpeedVariation(5.0, 20.0, 1.0, seed=1)
    xs = np.array([v.next() for _ in range(5000)])
    assert xs[0] == a[0]
    assert xs.min() >= 0.95 and xs.max() <= 1.05
    assert 0.01 < np.std(xs) < 0.03
    assert np.corrcoef(xs[:-1], xs[1:])[0, 1] > 0.9  # slow: one-second steps barely change it
    w = SpeedVariation(5.0, 20.0, 1.0, seed=2)
    assert [w.next() for _ in range(3)] != xs[:3].tolist()


@pytest.mark.parametrize("kind", ["radar", "wheel", "perfect"])
def test_speed_sensor_per_tick_equals_vectorized(kind):
    t = 1.0 + np.arange(4000) * 0.03
    v = 2.5 + 0.2 * np.sin(t)
    cfg = SpeedSensorConfig(kind, rate_hz=10.0)
    vec = SpeedSensor(cfg, seed=5).measure(t, v)
    s = SpeedSensor(cfg, seed=5)
    tick = np.array([s.read(a, b) for a, b in zip(t.tolist(), v.tolist(), strict=True)])
    assert np.array_equal(vec, tick)
    rel = vec / v - 1
    sigma, bias = {"radar": (0.01, 0.0), "wheel": (0.005, 0.03), "perfect": (0.0, 0.0)}[kind]
    assert np.mean(rel) == pytest.approx(bias, abs=0.002 + sigma * 0.1)
    assert np.std(rel) <= sigma * 1.2 + 0.004  # + the sample-and-hold lag on a changing speed


def test_speed_sensor_validation():
    with pytest.raises(VehicleError, match="kind must be one of"):
        SpeedSensorConfig("laser")
    with pytest.raises(VehicleError, match="rate_hz"):
        SpeedSensorConfig(rate_hz=0)
    with pytest.raises(VehicleError, match="strictly increasing"):
        SpeedSensor().measure([1.0, 1.0], [2.0, 2.0])


def test_sumos_modules_leave_the_process_proj_settings_as_they_were():
    """libsumo and sumo set PROJ_DATA to SUMO's older proj.db when unset; imported through vehicle it
    does not, so rasterio imported after it still resolves an EPSG code (a fresh process: the setting
    is process-wide)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("PROJ_DATA", "PROJ_LIB")}
    # libsumo, and the `sumo` package that finding netconvert (to build a network) imports
    for first in ("from vrsim.vehicle.driver import import_libsumo; import_libsumo()",
                  "from vrsim.vehicle.network import find_netconvert; find_netconvert()"):
        code = (f"{first}; import os, rasterio; from rasterio.crs import CRS;"
                "assert 'PROJ_DATA' not in os.environ and 'PROJ_LIB' not in os.environ;"
                "print(CRS.from_string('EPSG:2227').to_epsg())")
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                              timeout=120)
        assert done.returncode == 0, f"{first}: {done.stderr[-2000:]}"
        assert done.stdout.strip() == "2227"
