"""The loop analysis of a scenario's controller (`vrsim controller analyze`): margins, crossover and
bandwidth (`controller.analysis`), the measured response time (`controller.response`) and the
look-ahead it gives (`services.sim.look_ahead`), all on the scenario's machine and timing."""

from __future__ import annotations

from dataclasses import dataclass

from controller import ControllerConfig, PlantParams
from controller.analysis import LoopAnalysis, NotLinear, analyze_loop
from controller.config import LOOK_AHEAD_AUTO
from controller.response import ResponseTime, response_time
from services.sim.core import plant_for
from services.sim.look_ahead import initial_look_ahead_s, known_delay_s
from services.sim.scenario import Scenario


@dataclass(frozen=True)
class ControllerReport:
    """What `analyze_controller` found.

    Attributes
    ----------
    scenario : Scenario
    plant : PlantParams
        The scenario's plant with its implement's transmission ratio and shaft-speed limit.
    loop : LoopAnalysis or None
        None when the kind has no linear model (`no_loop_reason` says why).
    no_loop_reason : str
    response : ResponseTime
    look_ahead : dict
        ``delivery_delay_s``, ``fix_age_s``, ``mean_lag_s``, ``auto_s`` (their sum: what
        ``look_ahead_s = "auto"`` gives), ``used_s`` (what this scenario starts with) and ``tune``
        (its ``look_ahead_tune``).
    """

    scenario: Scenario
    plant: PlantParams
    loop: LoopAnalysis | None
    no_loop_reason: str
    response: ResponseTime
    look_ahead: dict

    @property
    def controller(self) -> ControllerConfig:
        return self.scenario.controller

    def to_dict(self) -> dict:
        """What ``vrsim controller analyze --json`` prints."""
        cfg = self.controller
        return {"scenario": self.scenario.name, "kind": cfg.kind,
                "loop": None if self.loop is None else self.loop.to_dict(),
                "no_loop_reason": self.no_loop_reason or None,
                "response": self.response.to_dict(), "look_ahead": self.look_ahead}


def analyze_controller(scenario: Scenario) -> ControllerReport:
    """Analyse the scenario's controller on its plant and timing (see the module docstring)."""
    plant, timing = plant_for(scenario), scenario.timing
    cfg = scenario.controller
    try:
        loop, reason = analyze_loop(plant, cfg, timing.control_period_s), ""
    except NotLinear as exc:
        loop, reason = None, str(exc)
    response = response_time(plant, cfg, timing.control_period_s, timing.plant_step_s)
    known = known_delay_s(scenario)
    auto_s = known + response.look_ahead_s     # what initial_look_ahead_s gives for "auto"
    used_s = auto_s if cfg.look_ahead_s == LOOK_AHEAD_AUTO else initial_look_ahead_s(scenario, plant)
    look_ahead = {"delivery_delay_s": scenario.implement.delivery_delay_s,
                  "fix_age_s": known - scenario.implement.delivery_delay_s,
                  "mean_lag_s": response.look_ahead_s, "auto_s": auto_s,
                  "used_s": used_s,
                  "tune": cfg.look_ahead_tune}
    return ControllerReport(scenario=scenario, plant=plant, loop=loop, no_loop_reason=reason,
                            response=response, look_ahead=look_ahead)
