"""The control core: fix -> landing point -> rate -> target shaft speed -> PID + plant -> product.

The one pure core that both `vrsim run` (the whole track at once) and the Zenoh controller service
(each lockstep batch, carrying its state over) call, so both give the same numbers.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from controller import PlantParams, build_loop
from controller.loop import StepOutput
from maps import Grid, RatePolicy
from services.sim.scenario import Scenario
from services.sim.sections import SectionSwitch


def plant_for(scenario: Scenario) -> PlantParams:
    """The scenario's plant with the implement's transmission ratio and shaft-speed limit: the machine
    is described once, in ``[implement]``."""
    imp = scenario.implement
    return dataclasses.replace(scenario.plant, transmission_ratio=imp.transmission_ratio,
                               shaft_rpm_max=imp.shaft_rpm_max)


class IdealMeter:
    """``[controller] kind = "ideal"``: a reference meter whose shaft turns at exactly the target each
    control period (no PID, no plant, no delay), so what it meters is exactly what the target asks.

    Runs with it measure the error left when metering is perfect: the geometry of landing, section
    control and machine limits. The reported current is the static current that would hold the target
    on the real plant (``target / shaft_rpm_per_a`` within the valve's range), for plots only.

    A seam, not a registry kind: the controller registry of branch ``ctl`` brings the same meter
    (``controller.kinds.ideal.IdealLoop``, same numbers); once it is on main, `meter_loop` is
    `controller.build_loop` and this class goes.
    """

    def __init__(self, plant: PlantParams, control_period_s: float):
        self.plant = plant
        self.control_period_s = control_period_s

    def run(self, targets_rpm) -> StepOutput:
        """One period per target (shape (K,)); outputs of shape (K, 1)."""
        r = np.minimum(np.maximum(np.asarray(targets_rpm, float), 0.0), self.plant.shaft_rpm_max)[:, None]
        current = np.clip(r / self.plant.shaft_rpm_per_a, self.plant.current_min_a, self.plant.current_max_a)
        return StepOutput(r, r * self.control_period_s / 60.0, current, r.copy())


REFERENCE_METERS = {"ideal": IdealMeter}  # controller.gains.REFERENCE_KINDS, built here


def meter_loop(scenario: Scenario):
    """The metering loop of the scenario's ``[controller]``: the PID with the paper's plant
    (`controller.build_loop`), or a reference meter (`REFERENCE_METERS`)."""
    timing = scenario.timing
    reference = REFERENCE_METERS.get(scenario.controller.kind)
    if reference is not None:
        return reference(plant_for(scenario), timing.control_period_s)
    return build_loop(plant_for(scenario), scenario.controller, control_period_s=timing.control_period_s,
                      plant_step_s=timing.plant_step_s, n=1)


class ControlCore:
    """Control ticks: fix -> landing point -> rate -> sections -> target rpm -> PID + plant -> product.

    Deterministic and free of I/O; `vrsim run` (the whole track in one `run_track`) and the
    controller service (`run_track` on each lockstep batch, the state carried over) run the same
    stages:

    1. `targets`: where product metered now will land, the prescription there (with the map's
       policy off the map), which sections apply (`services.sim.sections.SectionSwitch`, stateful:
       coverage control remembers where product landed) and the target shaft speed for the width
       whose gates are open. No feedback, so vectorized over ticks. The landing point is predicted
       by dead reckoning from the fix: product metered now lands `delivery_delay_s` later, when the
       implement has moved ``speed * delay`` along its heading.
    2. the closed loop (PID, valve, motor; or a reference meter, `meter_loop`) over the targets, one
       control period per tick (sequential by nature: one lifted matrix product per period).

    Parameters
    ----------
    grid : maps.Grid
        The prescription in the field's metric CRS.
    scenario : Scenario
    field_polygon : shapely geometry
        The field boundary (section control switches sections off outside it).
    path : vehicle.CoveragePath, optional
        The planned path (coverage section control reads off it where the path works).
    """

    def __init__(self, grid: Grid, scenario: Scenario, field_polygon, path=None):
        self.grid = grid
        self.implement = scenario.implement
        self.policy = RatePolicy(mode=scenario.map.policy,
                                 default_rate_kg_ha=scenario.map.default_rate_kg_ha)
        self.loop = meter_loop(scenario)
        self.switch = SectionSwitch(self.implement, field_polygon, path, scenario.timing.control_period_s,
                                    min(grid.cell_size))
        self.last_rate_kg_ha = float("nan")

    def targets(self, x_m, y_m, heading_rad, speed_m_s, implement_on, s_m=None) -> dict[str, np.ndarray]:
        """Stage 1 over arrays of ticks (shape (n,)); advances the policy's and the sections' memory.

        `s_m` is the distance along the planned path (coverage section control needs it)."""
        lead_m = np.asarray(speed_m_s) * self.implement.delivery_delay_s
        lx = x_m + lead_m * np.cos(heading_rad)
        ly = y_m + lead_m * np.sin(heading_rad)
        found = self.grid.lookup(lx, ly)
        rate = self.policy.apply(found.rate_kg_ha, found.inside, self.last_rate_kg_ha)
        if rate.size:
            self.last_rate_kg_ha = float(rate[-1])
        states = self.switch.step(x_m, y_m, heading_rad, speed_m_s, implement_on, s_m)
        width_on = states.width_on_m
        # Within the meter's speed range while applying; a zero rate or all sections off stop the shaft.
        wanted = self.implement.clip_shaft_rpm(self.implement.target_shaft_rpm(rate, speed_m_s, width_on))
        target = np.where(width_on > 0, wanted, 0.0)
        return {"landing_x_m": lx, "landing_y_m": ly, "prescribed_kg_ha": rate, "target_shaft_rpm": target,
                "width_on_m": width_on, "sections_on": states.actual, "sections_commanded": states.commanded}

    def run_track(self, x_m, y_m, heading_rad, speed_m_s, implement_on, s_m=None,
                  progress=None) -> dict[str, np.ndarray]:
        """All stages over the next ticks of a measured track; arrays keyed as `CONTROL_KEYS`."""
        rec = self.targets(x_m, y_m, heading_rad, speed_m_s, implement_on, s_m)
        targets, n = rec["target_shaft_rpm"], len(x_m)
        rpm, rev, cur = np.empty(n), np.empty(n), np.empty(n)
        chunk = 20000
        for start in range(0, n, chunk):
            part = slice(start, min(n, start + chunk))
            out = self.loop.run(targets[part])
            rpm[part], rev[part], cur[part] = out.shaft_rpm[:, 0], out.shaft_rev[:, 0], out.current_a[:, 0]
            if progress is not None:
                progress(part.stop, n)
        rec.update(shaft_rpm=rpm, shaft_rev=rev, current_a=cur,
                   metered_kg=self._metered_kg(rev, rec["width_on_m"] > 0))
        return {key: rec[key] for key in CONTROL_KEYS}

    def _metered_kg(self, shaft_rev, applying) -> np.ndarray:
        # Sections off close the gate: what the shaft turns then stays in the hopper. An underdamped
        # motor can swing briefly backwards when it brakes hard; a roller turning back meters nothing
        # (it does not lift product off the ground), so only forward revolutions count.
        forward = np.maximum(shaft_rev, 0.0)
        return np.where(np.asarray(applying, bool), self.implement.mass_kg(forward), 0.0)


# Per tick, shape (n,); ``sections_on`` and ``sections_commanded`` are (n, sections): each section's gate
# and the terminal's command to it (`services.sim.sections.SectionStates`).
CONTROL_KEYS = ("landing_x_m", "landing_y_m", "prescribed_kg_ha", "target_shaft_rpm", "shaft_rpm",
                "shaft_rev", "current_a", "metered_kg", "width_on_m", "sections_on", "sections_commanded")
