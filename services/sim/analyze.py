"""The loop analysis of a scenario's controller (`vrsim controller analyze`): margins, crossover and
bandwidth (`controller.analysis`), the measured response time (`controller.response`) and the
look-ahead it gives (`services.sim.look_ahead`), all on the loop the scenario's machine runs: the
controller as the run resolves it (`services.sim.as_run`) on the plant each of the machine's drives
closes (`services.sim.core.machine_plant`: a metering shaft's, a sprayer's flow loop at the map's
working point, the machine's dead time inside the loop), at the scenario's timing.

`margin_warning` says when a loop's margins are below the usual design minimums (`MIN_GAIN_MARGIN_DB`,
`MIN_PHASE_MARGIN_DEG`): `vrsim tune` prints it under the gains it found.
"""

from __future__ import annotations

from dataclasses import dataclass

from vrsim.controller import ControllerConfig, PlantParams
from vrsim.controller.analysis import LoopAnalysis, NotLinear, analyze_loop
from vrsim.controller.config import LOOK_AHEAD_AUTO
from vrsim.controller.response import ResponseTime, response_time
from vrsim.services.sim.core import machine_plant
from vrsim.services.sim.look_ahead import initial_look_ahead_s, known_delay_s
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.world import build_world

# Design minimums of a loop's stability margins (the classical 6 dB and 45 deg): below them a loop
# rings on its steps and a modest change of the plant's gain or lag (a warmer oil, a worn valve, a
# denser product) can make it unstable.
MIN_GAIN_MARGIN_DB = 6.0
MIN_PHASE_MARGIN_DEG = 45.0


@dataclass(frozen=True)
class ControllerReport:
    """What `analyze_controller` found.

    Attributes
    ----------
    scenario : Scenario
        As run (`services.sim.world.build_world`): its controller resolved as the run resolves it.
    plant : PlantParams
        The plant each of the machine's drives closes its loop on (`services.sim.core.machine_plant`).
    loop : LoopAnalysis or None
        None when the kind has no linear model (`no_loop_reason` says why).
    no_loop_reason : str
    response : ResponseTime
        In the loop's quantity (`quantity`, `unit`).
    look_ahead : dict
        ``delivery_delay_s``, ``fix_age_s``, ``mean_lag_s``, ``auto_s`` (their sum: what
        ``look_ahead_s = "auto"`` gives), ``used_s`` (what this scenario starts with) and ``tune``
        (its ``look_ahead_tune``).
    machine : str
        The machine's kind (``[implement] kind``).
    drives : int
        How many loops alike the machine runs (a drive per section, a sprayer's PWM sections).
    quantity, unit : str
        What the loop holds on target and its unit (`services.sim.machines.Machine.loop_quantity`).
    """

    scenario: Scenario
    plant: PlantParams
    loop: LoopAnalysis | None
    no_loop_reason: str
    response: ResponseTime
    look_ahead: dict
    machine: str
    drives: int
    quantity: str
    unit: str

    @property
    def controller(self) -> ControllerConfig:
        return self.scenario.controller

    def to_dict(self) -> dict:
        """What ``vrsim controller analyze --json`` prints."""
        cfg = self.controller
        return {"scenario": self.scenario.name, "kind": cfg.kind, "machine": self.machine,
                "drives": self.drives, "loop_quantity": self.quantity, "loop_unit": self.unit,
                "loop": None if self.loop is None else self.loop.to_dict(),
                "no_loop_reason": self.no_loop_reason or None,
                "response": self.response.to_dict(), "look_ahead": self.look_ahead}


def analyze_controller(scenario: Scenario) -> ControllerReport:
    """Analyse the scenario's controller on the loop its machine runs, at its timing (see the module
    docstring). `ScenarioError` for what the run refuses at its start (a sprayer's product that is not
    liquid, its nozzles that do not fit the boom, a controller that does not load)."""
    world = build_world(scenario)
    scenario, timing = world.scenario, world.scenario.timing
    machine = machine_for(scenario.implement)
    plant, cfg = machine_plant(scenario, world.grid, machine), scenario.controller
    loop, reason = loop_of(plant, cfg, timing.control_period_s)
    response = response_time(plant, cfg, timing.control_period_s, timing.plant_step_s)
    known = known_delay_s(scenario)
    auto_s = known + response.look_ahead_s     # what initial_look_ahead_s gives for "auto"
    used_s = auto_s if cfg.look_ahead_s == LOOK_AHEAD_AUTO else initial_look_ahead_s(scenario, plant)
    look_ahead = {"delivery_delay_s": scenario.implement.delivery_delay_s,
                  "fix_age_s": known - scenario.implement.delivery_delay_s,
                  "mean_lag_s": response.look_ahead_s, "auto_s": auto_s,
                  "used_s": used_s,
                  "tune": cfg.look_ahead_tune}
    quantity, unit = machine.loop_quantity
    return ControllerReport(scenario=scenario, plant=plant, loop=loop, no_loop_reason=reason,
                            response=response, look_ahead=look_ahead, machine=scenario.implement.kind,
                            drives=machine.drives, quantity=quantity, unit=unit)


def loop_of(plant: PlantParams, cfg: ControllerConfig,
            control_period_s: float) -> tuple[LoopAnalysis | None, str]:
    """`cfg`'s loop on `plant` (`controller.analysis.analyze_loop`: python-control's
    `stability_margins`, ...), or None and why not (a kind without a linear model)."""
    try:
        return analyze_loop(plant, cfg, control_period_s), ""
    except NotLinear as exc:
        return None, str(exc)


def margin_warning(loop: LoopAnalysis | None) -> str | None:
    """One line when `loop`'s gain margin is below `MIN_GAIN_MARGIN_DB` or its phase margin below
    `MIN_PHASE_MARGIN_DEG` (or the closed loop is unstable); None otherwise, or for no linear loop."""
    if loop is None:
        return None
    if not loop.closed_loop_stable:
        return f"closed loop is UNSTABLE (gain margin {loop.gain_margin_db:.1f} dB)"
    low = []
    if loop.gain_margin_db < MIN_GAIN_MARGIN_DB:
        low.append(f"gain margin {loop.gain_margin:.3g} ({loop.gain_margin_db:.1f} dB) is below "
                   f"{MIN_GAIN_MARGIN_DB:g} dB")
    if loop.phase_margin_deg < MIN_PHASE_MARGIN_DEG:
        low.append(f"phase margin {loop.phase_margin_deg:.1f} deg is below {MIN_PHASE_MARGIN_DEG:g} deg")
    if not low:
        return None
    return (" and ".join(low) + ": the loop rings on its steps, and a little more plant gain or lag "
            "makes it unstable")
