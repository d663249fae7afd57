"""vrsim vehicle package: field geometry, coverage path, SUMO driving, implement/meter and GNSS.

Knows nothing of maps' formats, control or Zenoh. Positions are metres in the field's UTM CRS;
headings in the math convention (radians counter-clockwise from east) unless named ``*_deg``
(compass bearing, degrees clockwise from north).
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
