"""vrsim vehicle package: field geometry, coverage path, SUMO driving, implement/meter and GNSS.

Knows nothing of maps' formats, control or Zenoh. Positions are metres in the field's UTM CRS;
headings in the math convention (radians counter-clockwise from east) unless named ``*_deg``
(compass bearing, degrees clockwise from north).

One module per concept: `vehicle.field` (boundary, CRS), `vehicle.coverage` (headland passes,
serpentine swaths, turns from `vehicle.dubins`), `vehicle.network` (netconvert, cache),
`vehicle.driver` (libsumo, per-tick pose), `vehicle.gnss`, `vehicle.speed_sensor`,
`vehicle.implement` (meter, sections, the delivery delay's value) and `vehicle.sprayer` (nozzles, their
pressure range as the limit, the flow meter, PWM).
"""

from vrsim.vehicle.coverage import CoveragePath, Segment, plan_coverage
from vrsim.vehicle.driver import DriveConfig, Pose, SpeedVariation, SumoDriver
from vrsim.vehicle.field import Field, FieldWarning
from vrsim.vehicle.gnss import Gnss, GnssConfig
from vrsim.vehicle.implement import Implement
from vrsim.vehicle.network import build_network, default_cache_dir, find_netconvert
from vrsim.vehicle.speed_sensor import SpeedSensor, SpeedSensorConfig
from vrsim.vehicle.sprayer import FlowMeter, SprayerSpec
from vrsim.vehicle.track import track_on_path

__all__ = [
    "CoveragePath", "DriveConfig", "Field", "FieldWarning", "FlowMeter", "Gnss", "GnssConfig", "Implement",
    "Pose",
    "Segment", "SpeedSensor", "SpeedSensorConfig", "SpeedVariation", "SprayerSpec", "SumoDriver",
    "build_network",
    "default_cache_dir", "find_netconvert", "plan_coverage", "track_on_path",
]
