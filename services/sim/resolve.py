"""The scenario as run: every value a scenario leaves to a kind, resolved once to the number the run uses.

A scenario may leave values to its kinds: the controller's ``gains = "paper"`` (or "textbook",
"relay"), a controller kind's own defaults (its ``params``, a delay that defaults to the plant's
sensor delay), ``look_ahead_s`` unset or "auto", the GNSS ``kind`` (its error and correlation time)
and the speed sensor's ``kind`` (its noise and bias). `as_run` fills them in, in the same
dataclasses, before anything moves: `services.sim.world.build_world` calls it, so the world's scenario,
which the run consumes, is the one that summary.json, ``vrsim run --json`` (`with_settings`) and the
report's "Settings as run" show. Written out (`services.sim.scenario_toml.to_toml`), it loads and reruns to
the same figures.

What each becomes:

* PID family (kind P, PI, PID; "pid" becomes "PID"): ``gains = "manual"`` with the `kp`, `ki`, `kd`
  its source gives (`controller.resolve_gains`; `ki` only with an I term, `kd` with a D term);
* any other kind but ``python``: ``params`` with every key of its parameters (`KindParams.to_dict`);
  ``fuzzy_pid``'s base gains as for the PID family, ``smith``'s `model_delay_s` and ``ff_pi``'s
  `reference_delay_s` the plant's sensor delay when unset (`SENSOR_DELAY_KEYS`); a ``python`` kind's
  params are the user's and stay as given;
* ``look_ahead_s``: seconds (`services.sim.look_ahead.initial_look_ahead_s`), but a ``python``
  controller's "auto" stays "auto" (the run's control core measures it): measuring it runs the user's
  code, which only the run's controller may do; the bus's services build worlds of scenarios that
  came over the network, and only the controller service checks where user code may run from;
* ``[gnss]`` `sigma_m`, `tau_s` and ``[speed_sensor]`` `noise_pct`, `bias_pct`: their class's values
  where unset (`vehicle.GnssConfig.resolved`, `vehicle.SpeedSensorConfig.resolved`).

Resolving is idempotent: the scenario as run of a scenario as run is itself.

The plant as run (`plant_for`: the scenario's plant with the implement's transmission ratio and
shaft-speed limit) and the scenario as plain data with it (`config_as_run`) are here too, below world
building and the control core: `services.sim.core` re-exports them, `services.sim.as_run` the
resolving beside `with_settings`, which reads a finished run.
"""

from __future__ import annotations

import dataclasses

from vrsim.common import ControllerError, ScenarioError
from vrsim.controller import ControllerConfig, PlantParams, gains_from_source, resolve_gains
from vrsim.controller.config import LOOK_AHEAD_AUTO, PID_KINDS, USER_KIND
from vrsim.services.sim.look_ahead import initial_look_ahead_s
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.scenario_toml import as_dict

# Kinds whose parameter None means "the plant's sensor delay" (see each kind's params dataclass).
SENSOR_DELAY_KEYS = {"smith": "model_delay_s", "ff_pi": "reference_delay_s"}


def as_run(scenario: Scenario) -> Scenario:
    """`scenario` with every kind's default resolved to the value the run uses (see the module docstring).

    Raises
    ------
    ScenarioError
        ``"<file>: [controller] <message>"`` when the controller cannot be resolved (a relay experiment
        that fails, a loop that the "auto" look-ahead cannot measure), as the run would.
    """
    plant, cfg = plant_for(scenario), scenario.controller
    try:
        controller = resolved_controller(cfg, plant, scenario.timing.control_period_s)
        if not (cfg.kind == USER_KIND and cfg.look_ahead_s == LOOK_AHEAD_AUTO):
            controller = dataclasses.replace(controller, look_ahead_s=initial_look_ahead_s(scenario, plant))
    except ControllerError as exc:
        raise ScenarioError(f"{scenario.source}: [controller] {exc}") from None
    return dataclasses.replace(scenario, gnss=scenario.gnss.resolved(),
                               speed_sensor=scenario.speed_sensor.resolved(), controller=controller)


def resolved_controller(cfg: ControllerConfig, plant: PlantParams,
                        control_period_s: float) -> ControllerConfig:
    """`cfg` with its gains and its kind's defaults as numbers, for `plant` at `control_period_s` [s]
    (the look-ahead is the scenario's business: `as_run`). The same controller: its loop gives the same
    numbers bit for bit."""
    if cfg.kind in PID_KINDS:
        g, terms = resolve_gains(cfg, plant, control_period_s), PID_KINDS[cfg.kind]
        return dataclasses.replace(cfg, kind=terms, gains="manual", kp=g.kp,
                                   ki=g.ki if "I" in terms else None, kd=g.kd if "D" in terms else None)
    if cfg.kind == USER_KIND:
        return cfg
    params = cfg.kind_params().to_dict()
    if "gains" in params:   # fuzzy_pid: a PID's base gains
        g = gains_from_source(params["gains"], "PID", plant, control_period_s,
                              params["kp"], params["ki"], params["kd"])
        params.update(gains="manual", kp=g.kp, ki=g.ki, kd=g.kd)
    delay_key = SENSOR_DELAY_KEYS.get(cfg.kind)
    if delay_key is not None and params[delay_key] is None:
        params[delay_key] = plant.sensor_delay_s
    return dataclasses.replace(cfg, params={k: v for k, v in params.items() if v is not None})


def plant_for(scenario: Scenario) -> PlantParams:
    """The scenario's plant with the implement's transmission ratio and shaft-speed limit: the machine
    is described once, in ``[implement]``."""
    imp = scenario.implement
    return dataclasses.replace(scenario.plant, transmission_ratio=imp.transmission_ratio,
                               shaft_rpm_max=imp.shaft_rpm_max)


def config_as_run(scenario: Scenario) -> dict:
    """The scenario as plain data with the parameters as the run used them (the plant with the
    implement's transmission ratio and shaft-speed limit, `plant_for`): summary.json's
    ``scenario_config`` and the report's settings."""
    return dict(as_dict(scenario), plant=dataclasses.asdict(plant_for(scenario)))
