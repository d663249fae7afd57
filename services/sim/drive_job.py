"""What SUMO needs to drive a scenario's planned path (`DriveJob`), and driving it (`DriveJob.driving`).

Vehicle-room objects only, so that SUMO's process in a streamed run (`services.sim.drive_worker`)
imports libsumo and `vehicle`, not the scenario's parser, the controllers or the maps; and one place
that turns a scenario into a `vehicle.SumoDriver`, for that process, the in-process run and the vehicle
service alike (`services.sim.world.driving`).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass

from vrsim.common.errors import ScenarioError, VehicleError
from vrsim.vehicle import CoveragePath, DriveConfig, SumoDriver


@dataclass(frozen=True)
class DriveJob:
    """A planned path and how to drive it.

    Attributes
    ----------
    path : CoveragePath
    tractor : DriveConfig
        The scenario's ``[tractor]``.
    step_s : float
        SUMO's step: ``[timing] sumo_step_s``, by default the control period, s.
    seed : int
    max_time_s : float or None
        ``[timing] max_sim_time_s``, s; None: the driver derives it from the path.
    source : str
        The scenario's file (or built-in name), which errors name.
    tick_s : float or None
        The control period, s, when SUMO steps at a multiple of it (the ticks between its steps are
        interpolated: `vehicle.SumoDriver`); None: every tick is a SUMO step.
    """

    path: CoveragePath
    tractor: DriveConfig
    step_s: float
    seed: int
    max_time_s: float | None
    source: str
    tick_s: float | None = None

    @classmethod
    def of(cls, scenario, path: CoveragePath) -> DriveJob:
        """The job of a `services.sim.scenario.Scenario` on its planned `path`."""
        timing = scenario.timing
        coarser = timing.sumo_step_s is not None and timing.sumo_step_s != timing.control_period_s
        step_s = timing.sumo_step_s if coarser else timing.control_period_s
        return cls(path, scenario.tractor, step_s, scenario.seed, timing.max_sim_time_s, scenario.source,
                   timing.control_period_s if coarser else None)

    @contextmanager
    def driving(self):
        """A `vehicle.SumoDriver` on the path, as a context manager; a `VehicleError` while driving
        becomes a `ScenarioError` naming the scenario."""
        try:
            with SumoDriver(self.path, self.tractor, step_s=self.step_s, seed=self.seed,
                            max_time_s=self.max_time_s, tick_s=self.tick_s) as driver:
                yield driver
        except VehicleError as exc:
            raise ScenarioError(f"{self.source}: {exc}") from None
