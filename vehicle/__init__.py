"""vrsim vehicle package: field geometry, coverage path, SUMO driving, implement/meter and GNSS.

Knows nothing of maps' formats, control or Zenoh. Positions are metres in the field's UTM CRS;
headings in the math convention (radians counter-clockwise from east) unless named ``*_deg``
(compass bearing, degrees clockwise from north).

One module per concept: `vehicle.field` (boundary, CRS), `vehicle.coverage` (headland passes,
serpentine swaths, turns from `vehicle.dubins`), `vehicle.network` (netconvert, cache),
`vehicle.driver` (libsumo, per-tick pose), `vehicle.gnss`, `vehicle.speed_sensor`,
`vehicle.implement` (meter, sections, delivery delay) and `vehicle.record` (the per-tick record).
"""

from vehicle.coverage import CoveragePath, Segment, plan_coverage
from vehicle.driver import DriveConfig, Pose, SpeedVariation, SumoDriver
from vehicle.field import Field
from vehicle.gnss import Gnss, GnssConfig
from vehicle.implement import DelayLine, Implement
from vehicle.network import build_network, default_cache_dir, find_netconvert
from vehicle.record import vehicle_record
from vehicle.speed_sensor import SpeedSensor, SpeedSensorConfig

__all__ = [
    "CoveragePath", "DelayLine", "DriveConfig", "Field", "Gnss", "GnssConfig", "Implement", "Pose",
    "Segment", "SpeedSensor", "SpeedSensorConfig", "SpeedVariation", "SumoDriver", "build_network",
    "default_cache_dir", "find_netconvert", "plan_coverage", "vehicle_record",
]
