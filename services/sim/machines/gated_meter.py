"""``gated_meter``: one metering shaft for the whole width, a gate per section (today's machine).

The shaft's target is for the rate at the implement's centre, looked up where product metered now
lands (`Motion.ahead`: the sensed speed, acceleration and yaw rate along the arc), at the centre's
sensed ground speed, over the width whose gates are open. Its product is shared between the open
sections by width, each share a strip along its section's own path (`maps.Strips`).
"""

from __future__ import annotations

import numpy as np

from vrsim.services.sim.machines.base import Machine
from vrsim.services.sim.machines.registry import register_machine
from vrsim.services.sim.section_landing import StripPlan
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle.machines import GatedMeter as GatedMeterKeys


@register_machine
class GatedMeter(Machine):
    """One drive, gates per section (see the module's docstring)."""

    kind = "gated_meter"
    keys = GatedMeterKeys

    def landing(self, motion: Motion, lead_s: float) -> tuple[np.ndarray, ...]:
        x, y, _, _ = motion.ahead(lead_s)
        return x, y, x[:, None], y[:, None]

    def drive_open(self, states: SectionStates) -> np.ndarray:
        return (states.width_on_m > 0)[:, None]

    def drive_targets(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        imp, width_on = self.implement, states.width_on_m
        # Within the meter's speed range while applying; a zero rate or all sections off stop the shaft.
        wanted = imp.clip_shaft_rpm(imp.target_shaft_rpm(rate_kg_ha[:, 0], states.motion.speed_m_s, width_on))
        return np.where(width_on > 0, wanted, 0.0)[:, None]

    def combined(self, per_drive: np.ndarray) -> np.ndarray:
        return per_drive[:, 0]

    def prescribed(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        return rate_kg_ha[:, 0]

    def deposition(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                   cell_m: float, ticks=None, tick_m: float | None = None, first_tick: int = 0) -> StripPlan:
        return StripPlan.of(track, states, delay_s, period_s, cell_m, ticks, tick_m, first_tick)
