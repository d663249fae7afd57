"""vrsim controller package: the paper's valve-controlled hydraulic motor, the rate controllers that
drive it (a registry of kinds behind one interface), tuning, loop analysis and step metrics, and the
sprayer's flow plant (`controller.flow_plant`), which the same kinds close.

Pure: numpy, scipy and python-control only, no I/O beyond reading a user's controller file and the
package's data; knows nothing of maps, SUMO or Zenoh.
"""

from vrsim.controller.config import ControllerConfig
from vrsim.controller.context import ContextTrack, ControlContext
from vrsim.controller.experiment import PaperRun, paper_experiment, run_paper
from vrsim.controller.factory import (
    build_controller,
    build_loop,
    build_variant_loops,
    loop_info,
    resolve_gains,
)
from vrsim.controller.flow_plant import FlowLinearization, FlowLoop, FlowPlant, linearize_flow
from vrsim.controller.gains import PidGains, paper_gains, ziegler_nichols
from vrsim.controller.interface import Controller, LoopInfo
from vrsim.controller.kinds.ideal import IdealLoop
from vrsim.controller.kinds.python import UserCodeError
from vrsim.controller.loop import ClosedLoop
from vrsim.controller.loop_io import StepOutput
from vrsim.controller.metrics import StepMetrics, step_metrics
from vrsim.controller.plant import PlantParams, assumptions, state_space, unlimited
from vrsim.controller.plant_loop import PlantLoop
from vrsim.controller.registry import KINDS
from vrsim.controller.simulate import SimResult, simulate
from vrsim.controller.tuning import (
    RelayResult,
    SensorFit,
    UltimateResult,
    fit_sensor,
    gains_from_source,
    pulse_response,
    relay_autotune,
    ultimate_from_pulse,
    ultimate_gain_experiment,
)

__all__ = [
    "KINDS", "ClosedLoop", "ContextTrack", "ControlContext", "Controller", "ControllerConfig",
    "FlowLinearization", "FlowLoop", "FlowPlant", "IdealLoop",
    "LoopInfo", "PaperRun", "PidGains",
    "PlantLoop", "PlantParams", "RelayResult", "SensorFit", "SimResult", "StepMetrics", "StepOutput",
    "UltimateResult", "UserCodeError", "assumptions", "build_controller", "build_loop", "build_variant_loops",
    "fit_sensor",
    "gains_from_source", "linearize_flow", "loop_info", "paper_experiment", "paper_gains", "pulse_response",
    "relay_autotune",
    "resolve_gains", "run_paper", "simulate", "state_space", "step_metrics", "ultimate_from_pulse",
    "ultimate_gain_experiment", "unlimited", "ziegler_nichols",
]
