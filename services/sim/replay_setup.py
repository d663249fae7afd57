"""The machine a replay runs: the user's scenario, or one made from the log, with the log's sections.

A log says what the machine did: its sections and their widths, its working speed and its rate unit.
`replay_scenario` puts those into the scenario's implement (a volume rate is a sprayer's: without a
scenario, a boom with flow control whose nozzles suit the log's rate and speed; a mass rate the
built-in default's metering shaft), then applies a machine fragment (a ``machine_fit.toml`` from
`vrsim fit`, `services.sim.overrides.machine_overrides`), whose keys are set as ``--set`` would set
them and checked as a scenario file's.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim.common import ScenarioError
from vrsim.maps.log_records import MachineRecords
from vrsim.maps.units import convert_rate, rate_kind
from vrsim.services.sim.overrides import Override
from vrsim.services.sim.scenario import Scenario, parse, read
from vrsim.services.sim.scenario_toml import to_toml
from vrsim.vehicle.sprayer import NOZZLE_FLOW_L_MIN, boom_flow_l_min

__all__ = ["replay_scenario"]

# Nozzle spacings booms are built with, m (25, 30, 50, 75 cm; 10, 15, 20, 30 in), largest first.
SPACINGS_M = (0.762, 0.75, 0.508, 0.5, 0.381, 0.3, 0.254, 0.25)
LIQUID_DENSITY_KG_L = 1.0   # a tank mix without a stated density: water's (the log's rates are volumes)
SPEED_MIN_M_S = 0.5


def replay_scenario(records: MachineRecords, scenario: Scenario | None = None,
                    fragment: list[Override] = ()) -> Scenario:
    """The scenario a replay of `records` runs: `scenario` (default: one made from the log) with
    `fragment`'s keys set, then its implement's sections set to the log's: the log says what the
    machine did, whatever sections a machine file fitted on another log has (see the module
    docstring). A sprayer whose nozzle spacing does not divide the log's sections gets one that does."""
    if scenario is None:
        text, source, base_dir = _default_text(records), f"{records.source} (machine from the log)", "."
    else:
        text, source, base_dir = to_toml(scenario), scenario.source, scenario.base_dir
    overrides = [*fragment, *_section_overrides(records)]
    machine = parse(text, source, base_dir, overrides=overrides)
    widths = machine.implement.section_widths
    if machine.implement.kind == "sprayer" and not _fits(machine.implement.machine.nozzle_spacing_m, widths):
        machine = parse(text, source, base_dir,
                        overrides=[*overrides, ("implement.nozzle_spacing_m", _spacing(records))])
    _check_unit(records, machine)
    return machine


def _check_unit(records: MachineRecords, machine: Scenario) -> None:
    """A log of a volume rate is a liquid's: the machine replaying it must meter one."""
    unit = records.unit or "kg/ha"
    if rate_kind(unit) == "volume" and machine.product.form != "liquid":
        raise ScenarioError(f"{machine.source}: [product] form = {machine.product.form!r}, but "
                            f"{records.source} logs a volume rate ({unit}): replay it with a machine that "
                            "meters a liquid (a sprayer's --scenario or --machine)")


def _moving_speed_m_s(records: MachineRecords) -> float:
    moving = records.speed_m_s[(records.speed_m_s > SPEED_MIN_M_S) & records.sections_on.any(axis=1)]
    return float(np.median(moving)) if moving.size else 2.5


def _section_overrides(records: MachineRecords) -> list[Override]:
    widths = [round(float(w), 6) for w in records.section_widths_m]
    return [("implement.width_m", round(sum(widths), 6)), ("implement.section_widths_m", widths),
            ("implement.sections", len(widths)),
            ("tractor.working_speed_m_s", round(_moving_speed_m_s(records), 3)),
            # The log's gates are what the terminal switched: no switch of vrsim's.
            ("implement.section_control", "off")]


def _fits(spacing: float, widths) -> bool:
    return all(abs(w / spacing - round(w / spacing)) * spacing < 0.01 * spacing for w in widths)


def _spacing(records: MachineRecords) -> float:
    widths = list(records.section_widths_m)
    for s in SPACINGS_M:
        if _fits(s, widths):
            return s
    narrow = min(widths)
    return narrow / max(1, round(narrow / 0.5))   # one nozzle per part of the narrowest section


def _default_text(records: MachineRecords) -> str:
    """A scenario for a log with no machine given: a sprayer for a volume rate, else the default's."""
    unit = records.unit or "kg/ha"
    if rate_kind(unit) != "volume":
        text, _, _ = read(None)
        return text
    spacing = _spacing(records)
    speed = _moving_speed_m_s(records)
    target = records.target[np.isfinite(records.target) & (records.target > 0)]
    rate_l_ha = float(convert_rate(np.median(target), unit, "L/ha")) if target.size else 100.0
    flow = float(boom_flow_l_min(rate_l_ha, speed, spacing))
    nozzle = min(NOZZLE_FLOW_L_MIN, key=lambda k: abs(math.log(flow / NOZZLE_FLOW_L_MIN[k])))
    return f"""name = "replay"
description = "the machine of an as-applied log: a boom sprayer with flow control"
[field]
rectangle = {{ width_m = 100.0, length_m = 100.0, lat = 0.0, lon = 0.0 }}
[map]
synthetic = "uniform"
[implement]
kind = "sprayer"
width_m = 12.0
delivery_delay_s = 0.0
nozzle = "{nozzle}"
nozzle_spacing_m = {spacing!r}
control = "flow"
[product]
name = "tank mix"
form = "liquid"
density_kg_l = {LIQUID_DENSITY_KG_L!r}
"""
