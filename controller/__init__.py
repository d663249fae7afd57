"""vrsim controller package: the paper's valve-controlled hydraulic motor, PID variants, tuning, metrics.

Pure: numpy and scipy only, no I/O, no clock; knows nothing of maps, SUMO or Zenoh.
"""

from controller.experiment import PaperRun, paper_experiment, run_paper
from controller.gains import ControllerConfig, PidGains, paper_gains, resolve_gains, ziegler_nichols
from controller.loop import ClosedLoop, StepOutput, build_loop
from controller.metrics import StepMetrics, step_metrics
from controller.plant import PlantParams, assumptions, state_space
from controller.simulate import SimResult, simulate, unlimited
from controller.tuning import (
    RelayResult,
    SensorFit,
    UltimateResult,
    fit_sensor,
    pulse_response,
    relay_autotune,
    ultimate_from_pulse,
    ultimate_gain_experiment,
)

__all__ = [
    "ClosedLoop", "ControllerConfig", "PaperRun", "PidGains", "PlantParams", "RelayResult", "SensorFit",
    "SimResult", "StepMetrics", "StepOutput", "UltimateResult", "assumptions", "build_loop", "fit_sensor",
    "paper_experiment", "paper_gains", "pulse_response", "relay_autotune", "resolve_gains", "run_paper",
    "simulate", "state_space", "step_metrics", "ultimate_from_pulse", "ultimate_gain_experiment",
    "unlimited", "ziegler_nichols",
]
