"""The field side of `vrsim serve aog-rc`: the scenario's SUMO drive as AgOpenGPS (through AgIO) tells
the Rate Controller app, and the run's usual outputs from what the emulated modules metered.

SUMO drives the whole path first (the tractor's path does not depend on the metering, as in `vrsim
run`); the stage of the control core that does not feed back (`services.sim.core.ControlCore.targets`:
the sections each tick, the prescription at the landing points) runs over it too. The service then
plays it tick by tick in real time: each tick's speed and sections go out as AgIO's PGNs 254, 239 and
229, and the drive's revolutions come from the module the app commands (`record`). At the end,
`result` meters and lands them as `vrsim run` does (`services.sim.run.accounted`).
"""

from __future__ import annotations

import numpy as np

from vrsim.services.aog.pgn import MachineData, SectionData, SteerData
from vrsim.services.sim.accounting import StageTimer
from vrsim.services.sim.core import ControlCore, machine_plant
from vrsim.services.sim.run import RunResult, accounted, drive

__all__ = ["FieldRun", "agio_messages"]

MS_TO_KMH = 3.6


def agio_messages(speed_m_s: float, sections_on: np.ndarray, left_m_s: float, right_m_s: float) -> list:
    """AgIO's PGNs 254, 239 and 229 for one moment: ground speed, the sections on (bool per section,
    up to 64; 254 and 239 carry the first 16 as relay bytes) and the boom ends' speeds."""
    bits = 0
    for i, on in enumerate(np.asarray(sections_on, bool)[:64]):
        bits |= int(on) << i
    kmh = max(speed_m_s, 0.0) * MS_TO_KMH
    return [SteerData(kmh, bits & 0xFFFF), MachineData(kmh, bits & 0xFFFF),
            SectionData(bits, max(left_m_s, 0.0), max(right_m_s, 0.0))]


class FieldRun:
    """A scenario driven, its per-tick sections and prescription, and the drives' revolutions as the
    modules turn them.

    Parameters
    ----------
    scenario : services.sim.scenario.Scenario
    drives : int
        How many of the service's sensors drive the machine's metering drives, in order (the machine's
        ``drives``; the others run on its plant off the map).
    """

    def __init__(self, scenario):
        self.drive = drive(scenario)
        world, track = self.drive.world, self.drive.track
        self.world, self.scenario = world, world.scenario
        self.core = ControlCore(world.grid, self.scenario, world.field.polygon, world.path)
        self.plant = machine_plant(self.scenario, world.grid, self.core.machine)
        d = self.drive
        self.stage = self.core.targets(d.measured_x_m, d.measured_y_m, track["heading_rad"],
                                       d.measured_speed_m_s, track["implement_on"], track["s_m"])
        self.period_s = self.scenario.timing.control_period_s
        self.ticks = len(track["time_s"])
        self.drives = self.core.machine.drives
        self.section_widths_m = np.asarray(self.scenario.implement.section_widths, float)
        n = self.ticks
        self.target_upm = np.zeros((n, self.drives))
        self.rev = np.zeros((n, self.drives))
        self.rpm = np.zeros((n, self.drives))
        self.current_a = np.zeros((n, self.drives))
        self.done = 0
        heading = np.unwrap(np.asarray(track["heading_rad"], float))
        self._yaw_rad_s = np.gradient(heading, self.period_s) if n > 1 else np.zeros(n)

    @property
    def units_per_rev(self) -> float:
        """Units (kg by the configured constant) per loop revolution: kg per shaft revolution, or a
        sprayer's litre times the product's density."""
        return float(self.core.machine.configured_kg(1.0, self.scenario.product))

    def agio(self, k: int) -> list:
        """Tick `k`'s AgIO messages (`agio_messages`)."""
        speed = float(self.drive.measured_speed_m_s[k])
        half = 0.5 * float(self.section_widths_m.sum())
        yaw = float(self._yaw_rad_s[k])
        return agio_messages(speed, self.stage["sections_on"][k], speed - yaw * half, speed + yaw * half)

    def record(self, k: int, drive: int, target_upm: float, rev: float, rpm: float, current_a: float) -> None:
        """What drive `drive`'s module did in tick `k`: the app's target (units/min) and the plant's
        revolutions, speed and current."""
        self.target_upm[k, drive], self.rev[k, drive] = target_upm, rev
        self.rpm[k, drive], self.current_a[k, drive] = rpm, current_a
        self.done = max(self.done, k + 1)

    def result(self) -> RunResult:
        """The run over the ticks played (`vrsim run`'s result: map, sections, figures)."""
        n = self.done
        track = {key: value[:n] if isinstance(value, np.ndarray) and len(value) == self.ticks else value
                 for key, value in self.drive.track.items()}
        stage = {key: value[:n] for key, value in self.stage.items()}
        machine = self.core.machine
        # The app's target where the drive's product reaches the ground (a closed drive's is 0, as the
        # run's own: the error split's reference meters the targets); aog_rc.csv keeps what it sent.
        drive_target_rpm = np.where(stage["drive_open"], self.target_upm[:n] / self.units_per_rev, 0.0)
        drive_kg, metered = self.core.metered(self.rev[:n], stage["drive_open"])
        control = dict(stage, drive_target_rpm=drive_target_rpm,
                       target_shaft_rpm=machine.combined(drive_target_rpm), drive_rev=self.rev[:n],
                       shaft_rpm=machine.combined(self.rpm[:n]), shaft_rev=machine.combined(self.rev[:n]),
                       current_a=machine.combined(self.current_a[:n]),
                       drive_kg=drive_kg, metered_kg=metered)
        d = self.drive
        measured = (d.measured_x_m[:n], d.measured_y_m[:n], d.measured_speed_m_s[:n])
        return accounted(self.world, track, measured, control, StageTimer(d.stage_s), d.started_unix)
