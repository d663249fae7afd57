"""vrsim controller package: the paper's valve-controlled hydraulic motor, PID variants, tuning, metrics.

Pure: numpy and scipy only, no I/O, no clock; knows nothing of maps, SUMO or Zenoh.
"""

from controller.gains import ControllerConfig, PidGains, paper_gains, resolve_gains, ziegler_nichols
from controller.loop import ClosedLoop, StepOutput, build_loop
from controller.plant import PlantParams, state_space

__all__ = [
    "ClosedLoop", "ControllerConfig", "PidGains", "PlantParams", "StepOutput", "build_loop",
    "paper_gains", "resolve_gains", "state_space", "ziegler_nichols",
]
