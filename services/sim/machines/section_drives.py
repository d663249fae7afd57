"""``section_drives``: a metering drive and control loop per section, so per-section rates and turn
compensation follow.

Each section's drive meters ``kg_per_rev * w_i / width_m`` per revolution (`vehicle.machines`): it
turns at the speed the one shaft would for the same rate and ground speed, within the same range.
Its target is for the rate at the section's own landing point (the section's centre, at its offset
across the pose predicted along the arc, `Motion.ahead`: a section travels ``d - w t o`` in a turn, so
each looks ahead by its own speed and the tractor's acceleration) and, with ``turn_compensation``, at
the section's own ground speed ``v - w o`` (the centre's sensed speed v minus the yaw rate w times
the section's offset o, left positive; never below 0: a section beyond the turn's pivot stands or
runs backwards and meters nothing). A closed section stops its drive. Each section's strip carries
its own drive's product (`StripPlan` with ``own_drives``).
"""

from __future__ import annotations

import numpy as np

from vrsim.services.sim.machines.base import Machine
from vrsim.services.sim.machines.registry import register_machine
from vrsim.services.sim.section_landing import StripPlan
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle.machines import SectionDrives as SectionDrivesKeys


@register_machine
class SectionDrives(Machine):
    """A drive per section (see the module's docstring)."""

    kind = "section_drives"
    keys = SectionDrivesKeys

    @property
    def drives(self) -> int:
        return self.implement.sections

    @property
    def drive_share(self) -> np.ndarray:
        return self.implement.section_widths / self.implement.width_m

    def landing(self, motion: Motion, lead_s: float) -> tuple[np.ndarray, ...]:
        x, y, cos, sin = motion.ahead(lead_s)
        offset_m = self.implement.section_offsets_m
        # Left of the predicted heading (cos, sin) is (-sin, cos).
        return x, y, x[:, None] - sin[:, None] * offset_m, y[:, None] + cos[:, None] * offset_m

    def drive_open(self, states: SectionStates) -> np.ndarray:
        return states.actual

    def drive_speed_m_s(self, motion: Motion) -> np.ndarray:
        """Each section's ground speed, m/s (n, sections): its own in a turn with turn compensation
        (``v - yaw_rate * offset``, at least 0), else the centre's sensed speed."""
        v = motion.speed_m_s[:, None]
        if not self.implement.machine.turn_compensation:
            return np.broadcast_to(v, (v.shape[0], self.drives))
        return np.maximum(motion.ground_speed_m_s(self.implement.section_offsets_m), 0.0)

    def drive_targets(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        imp = self.implement
        # A drive meters its section's share per revolution: its speed is the whole shaft's for its rate.
        wanted = imp.clip_shaft_rpm(imp.target_shaft_rpm(rate_kg_ha, self.drive_speed_m_s(states.motion)))
        return np.where(states.actual, wanted, 0.0)

    def combined(self, per_drive: np.ndarray) -> np.ndarray:
        return per_drive @ self.drive_share

    def prescribed(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        """The open sections' rates weighted by their widths (all sections' where none is open)."""
        weight = np.where(states.actual.any(axis=1, keepdims=True), states.actual, True) * self.drive_share
        return (rate_kg_ha * weight).sum(axis=1) / weight.sum(axis=1)

    def deposition(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                   cell_m: float, ticks=None, tick_m: float | None = None, first_tick: int = 0) -> StripPlan:
        return StripPlan.of(track, states, delay_s, period_s, cell_m, ticks, tick_m, first_tick,
                            own_drives=True)
