"""The in-process run: world, SUMO, sensors, control core, landing and metrics, staged.

Data flow of one control tick (docs/design.md draws it)::

    SUMO pose --GNSS--> measured fix --look-ahead by the delivery delay--> landing point
    --map lookup--> rate kg/ha --with speed, width, kg/rev--> target shaft rpm --PID--> valve current
    --hydraulic plant--> shaft revolutions --x kg/rev--> kg metered --lands after the delay--> map

The control part is `services.sim.core.ControlCore`, the one core that the Zenoh controller
service calls too. The stages that do not feed back (driving, GNSS
noise, where product lands, the as-applied raster, the metrics) are vectorized over the whole run:
the vehicle's path does not depend on the metering, so SUMO can drive the whole path first and the
control loop follow it.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from vrsim.common import ScenarioError, files
from vrsim.controller import ControllerConfig
from vrsim.services.sim.accounting import StageTimer, cells_in_field, check_world
from vrsim.services.sim.bounded import BoundedAccount
from vrsim.services.sim.core import ControlCore
from vrsim.services.sim.resolve import as_run
from vrsim.services.sim.result import RunResult
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.world import World, build_world, driving
from vrsim.vehicle import Gnss, SpeedSensor

# `cells_in_field` and `check_world` are the accounting's; `vrsim run --check` and the benchmarks
# import them from here, with the run's other public names.
__all__ = ["Drive", "RunResult", "accounted", "cells_in_field", "check_world",
           "control_and_account", "drive", "measure", "run", "sensors", "start_up"]

SPEED_SENSOR_SEED_OFFSET = 1  # the speed sensor's noise is seeded apart from the GNSS noise
# Memory the in-process run keeps per control tick: ~35 float64 arrays (the track, the sensors, the
# targets, the loop's outputs, the landing) plus temporaries of the vectorized stages.
ARRAY_BYTES_PER_TICK = 400


@dataclass
class Drive:
    """What a run measures before any controller acts: the world, the true track SUMO drove and what
    the sensors read on it. The tractor's path does not depend on the metering, so one drive serves
    any number of controllers (`vrsim compare`: same seed, same track, same sensor noise).

    Attributes
    ----------
    world : World
    track : dict
        The true path (`vehicle.SumoDriver.run_all`).
    measured_x_m, measured_y_m, measured_speed_m_s : ndarray
        GNSS fix and ground-speed sensor reading per tick.
    stage_s : dict
        Wall time of ``build_s``, ``sumo_s`` and ``sensors_s`` [s].
    """

    world: World
    track: dict
    measured_x_m: np.ndarray
    measured_y_m: np.ndarray
    measured_speed_m_s: np.ndarray
    stage_s: dict
    started_unix: float  # when the drive began (the TimeLog's clock)


def run(scenario: Scenario, progress=None) -> RunResult:
    """Run a scenario in process and return everything it measured."""
    return control_and_account(drive(scenario), progress=progress)


def drive(scenario: Scenario) -> Drive:
    """Build the world, drive SUMO over the whole path and read the sensors (the controller-free part).

    Its arrays are the whole run's, kept for the Python API (`RunResult`: ``track``, ``control``, ...):
    a run too long for them is refused before SUMO drives (`vrsim run` accounts part by part instead,
    `services.sim.streamed`)."""
    started, timer = time.time(), StageTimer()
    with timer.stage("build_s"):
        world = build_world(scenario)
        _check_arrays(world)
    scenario = world.scenario   # as run: what the drive, the sensors and the outputs use
    with timer.stage("sumo_s"), driving(scenario, world.path) as driver:
        track = driver.run_all()
    with timer.stage("sensors_s"):
        x_meas, y_meas, v_meas = measure(scenario, track)
    return Drive(world=world, track=track, measured_x_m=x_meas, measured_y_m=y_meas,
                 measured_speed_m_s=v_meas, stage_s=timer.stage_s, started_unix=started)


def control_and_account(drive: Drive, controller: ControllerConfig | None = None,
                        progress=None) -> RunResult:
    """Run the control core over a drive and account for the product: the rest of `run`.

    Parameters
    ----------
    drive : Drive
        From `drive` (not changed: several controllers can share it).
    controller : ControllerConfig, optional
        Run this controller instead of the scenario's (the result's ``world.scenario`` carries it).
    progress : callable, optional
        ``progress(done_ticks, total_ticks)`` during the control loop.

    The summary's ``wall_time_s`` and ``stage_s`` count the drive's stages and this call's.
    """
    world, track = drive.world, drive.track
    if controller is not None:
        scenario = as_run(dataclasses.replace(world.scenario, controller=controller))
        world = dataclasses.replace(world, scenario=scenario)
    timer = StageTimer(drive.stage_s)   # as if the drive had run just now
    with timer.stage("control_s"):
        core = ControlCore(world.grid, world.scenario, world.field.polygon, world.path)
        control = core.run_track(drive.measured_x_m, drive.measured_y_m, track["heading_rad"],
                                 drive.measured_speed_m_s, track["implement_on"], track["s_m"], progress)
    measured = (drive.measured_x_m, drive.measured_y_m, drive.measured_speed_m_s)
    return accounted(world, track, measured, control, timer, drive.started_unix)


def accounted(world: World, track: dict, measured: tuple, control: dict, timer: StageTimer,
              started_unix: float) -> RunResult:
    """The `RunResult` of a driven and controlled track, its per-tick arrays kept: the one accounting
    (`services.sim.bounded.BoundedAccount`, which `vrsim run` feeds part by part) fed the whole track
    at once, in the timer's ``metrics_s``; the timer then gives the run's wall time.

    `measured` holds the measured x, y (m) and ground speed (m/s) per tick. `control` holds at least
    ``metered_kg``, ``width_on_m``, ``sections_on``, ``drive_target_rpm`` and ``drive_kg``
    (`services.sim.core.CONTROL_KEYS`; ``sections_commanded`` too from `vrsim run`): what `vrsim run`
    computes and what the monitor rebuilds from its records. ``track["tick"]``, when given, numbers
    the ticks the arrays hold: a record with gaps (the monitor's after it was down) lands each stretch
    on its own (no strip joins across a gap); ``ticks`` and ``sim_time_s`` count what is there.
    """
    account = BoundedAccount(world, timer, started_unix, arrays=True)
    account.add(track, measured[2], control)
    return account.result(measured=measured)


def _check_arrays(world: World) -> None:
    """Refuse an in-process run whose per-tick arrays would not fit in memory (the path's ticks at the
    working speed, `ARRAY_BYTES_PER_TICK` each)."""
    sc = world.scenario
    ticks = world.path.length_m / (sc.tractor.working_speed_m_s * sc.timing.control_period_s)
    files.check_memory(2 * ticks * ARRAY_BYTES_PER_TICK,  # the driver allocates twice the expected ticks
                       f"an in-process run of about {ticks:,.0f} ticks", f"{sc.source}: [field]",
                       ScenarioError)


def start_up(world: World) -> tuple[ControlCore, Gnss, SpeedSensor]:
    """What a run builds from its world before its first tick: the control core (the machine's loops,
    its product, the controller, the look-ahead) and the sensors. Whatever the run refuses at its start
    it refuses here, in one `ScenarioError` naming the file, the table and the key (a sprayer's product
    that is not liquid, nozzles that do not fit the boom, a controller that does not load): `vrsim run
    --check` builds it too, so it says no where the run would."""
    scenario = world.scenario
    return ControlCore(world.grid, scenario, world.field.polygon, world.path), *sensors(scenario)


def sensors(scenario: Scenario) -> tuple[Gnss, SpeedSensor]:
    """The GNSS receiver and the ground-speed sensor the controller reads, seeded from the scenario."""
    return (Gnss(scenario.gnss, seed=scenario.seed),
            SpeedSensor(scenario.speed_sensor, seed=scenario.seed + SPEED_SENSOR_SEED_OFFSET))


def measure(scenario: Scenario, track: dict):
    """Measured x, y (GNSS) and ground speed (speed sensor) over a whole true track."""
    gnss, speed = sensors(scenario)
    x, y = gnss.measure(track["time_s"], track["x_m"], track["y_m"])
    return x, y, speed.measure(track["time_s"], track["speed_m_s"])
