"""The in-process run: world, SUMO, sensors, control core, landing and metrics, staged.

Data flow of one control tick (see the README's picture)::

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
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from common import ScenarioError, VehicleError
from controller import ControllerConfig
from maps import AsApplied, Grid
from services.sim import metrics
from services.sim.core import ControlCore
from services.sim.landing import Landing, land, merged_strips
from services.sim.metrics import MapMetrics, TransitionMetrics, map_metrics, transitions
from services.sim.scenario import Scenario
from services.sim.world import World, build_world
from vehicle import Gnss, SpeedSensor, SumoDriver

SPEED_SENSOR_SEED_OFFSET = 1  # the speed sensor's noise is seeded apart from the GNSS noise


def cells_in_field(grid: Grid, polygon) -> np.ndarray:
    """Boolean (rows, cols): cells whose centre (`maps.Grid.cell_centres`) lies inside the polygon."""
    import shapely

    x, y = grid.cell_centres()
    return shapely.contains_xy(polygon, x[None, :], y[:, None])


@dataclass
class RunResult:
    world: World
    track: dict
    measured_x_m: np.ndarray
    measured_y_m: np.ndarray
    measured_speed_m_s: np.ndarray
    control: dict
    landing: Landing
    as_applied: AsApplied
    in_field: np.ndarray
    map_metrics: MapMetrics
    transition_metrics: TransitionMetrics
    stage_s: dict
    summary: dict
    started_unix: float  # when the run (or the services run it was rebuilt from) started, Unix time


@contextmanager
def driving(world: World):
    """A `vehicle.SumoDriver` on the world's path with the scenario's tractor, tick and time limit
    (``[timing] max_sim_time_s``; unset, the driver derives it from the path), as a context manager.

    `vrsim run` and the vehicle service both drive through this, so they stop at the same limit with
    the same message; a `VehicleError` while driving becomes a `ScenarioError` naming the scenario.
    """
    sc = world.scenario
    try:
        with SumoDriver(world.path, sc.tractor, step_s=sc.timing.control_period_s, seed=sc.seed,
                        max_time_s=sc.timing.max_sim_time_s) as driver:
            yield driver
    except VehicleError as exc:
        raise ScenarioError(f"{sc.source}: {exc}") from None


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
    """Build the world, drive SUMO over the whole path and read the sensors (the controller-free part)."""
    stage = {}
    started = time.time()
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        stage[name] = now - clock
        clock = now

    world = build_world(scenario)
    lap("build_s")
    with driving(world) as driver:
        track = driver.run_all()
    lap("sumo_s")
    x_meas, y_meas, v_meas = measure(scenario, track)
    lap("sensors_s")
    return Drive(world=world, track=track, measured_x_m=x_meas, measured_y_m=y_meas,
                 measured_speed_m_s=v_meas, stage_s=stage, started_unix=started)


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
        scenario = dataclasses.replace(world.scenario, controller=controller)
        world = dataclasses.replace(world, scenario=scenario)
    scenario = world.scenario
    stage = dict(drive.stage_s)
    clock = time.perf_counter()
    wall0 = clock - sum(stage.values())   # as if the drive had run just now

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        stage[name] = now - clock
        clock = now

    core = ControlCore(world.grid, scenario, world.field.polygon)
    control = core.run_track(drive.measured_x_m, drive.measured_y_m, track["heading_rad"],
                             drive.measured_speed_m_s, track["implement_on"], progress)
    lap("control_s")
    summary, rest = account(world, track, control, wall0)
    lap("metrics_s")
    summary["wall_time_s"] = time.perf_counter() - wall0
    summary["realtime_factor"] = summary["sim_time_s"] / summary["wall_time_s"]
    summary["stage_s"] = stage
    return RunResult(world=world, track=track, measured_x_m=drive.measured_x_m,
                     measured_y_m=drive.measured_y_m, measured_speed_m_s=drive.measured_speed_m_s,
                     control=control, stage_s=stage, summary=summary, started_unix=drive.started_unix,
                     **rest)


def sensors(scenario: Scenario) -> tuple[Gnss, SpeedSensor]:
    """The GNSS receiver and the ground-speed sensor the controller reads, seeded from the scenario."""
    return (Gnss(scenario.gnss, seed=scenario.seed),
            SpeedSensor(scenario.speed_sensor, seed=scenario.seed + SPEED_SENSOR_SEED_OFFSET))


def measure(scenario: Scenario, track: dict):
    """Measured x, y (GNSS) and ground speed (speed sensor) over a whole true track."""
    gnss, speed = sensors(scenario)
    x, y = gnss.measure(track["time_s"], track["x_m"], track["y_m"])
    return x, y, speed.measure(track["time_s"], track["speed_m_s"])


def summarize(world: World, track: dict, landing: Landing, mm: MapMetrics, tm: TransitionMetrics,
              wall0: float) -> dict:
    """The summary of a run from its figures (`metrics.summary`); ``realtime_factor`` is left 0 for the
    caller, who knows its wall time."""
    scenario, timing = world.scenario, world.scenario.timing
    n = len(track["time_s"])
    figures = {
        **dataclasses.asdict(mm), **dataclasses.asdict(tm),
        "field_area_ha": world.field.area_ha,
        "sim_time_s": n * timing.control_period_s,
        "wall_time_s": time.perf_counter() - wall0,
        "ticks": n,
        "realtime_factor": 0.0,  # the caller knows its wall time
        "path_length_m": float(landing.distance_m[-1]) if n else 0.0,
    }
    return metrics.summary(scenario.name, scenario.seed, figures)


def account(world: World, track: dict, control: dict, wall0: float):
    """Land the metered product, build the as-applied raster and compute the summary."""
    scenario, grid = world.scenario, world.grid
    implement, timing = scenario.implement, scenario.timing
    width_on = control.get("width_on_m", np.where(track["implement_on"], implement.width_m, 0.0))
    offset = control.get("offset_m", np.zeros(len(width_on)))
    landing = land(grid, track, control["metered_kg"], width_on, offset, implement.delivery_delay_s,
                   timing.control_period_s)
    acc = AsApplied(grid)
    acc.add_strips(*merged_strips(landing, control["metered_kg"], width_on, offset, min(grid.cell_size)))
    in_field = cells_in_field(grid, world.field.polygon)
    cell_w, cell_h = grid.cell_size
    mm = map_metrics(grid.rates_kg_ha, acc.applied_kg_ha, acc.coverage_fraction, in_field,
                     abs(cell_w * cell_h) / 1e4, float(control["metered_kg"].sum()), acc.outside_kg)
    tm = transitions(track["time_s"], landing.distance_m, landing.prescribed_kg_ha, landing.applied_kg_ha,
                     np.asarray(track["implement_on"], bool))
    summary = summarize(world, track, landing, mm, tm, wall0)
    rest = dict(landing=landing, as_applied=acc, in_field=in_field, map_metrics=mm, transition_metrics=tm)
    return summary, rest
