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

from controller import ControllerConfig
from maps import AsApplied, Grid
from services.sim import metrics
from services.sim.core import ControlCore
from services.sim.landing import Landing, land
from services.sim.limits import MachineCheck, machine_check, working_speeds
from services.sim.metrics import (
    LimitMetrics,
    MapMetrics,
    OverlapMetrics,
    TransitionMetrics,
    limit_metrics,
    map_metrics,
    overlap_metrics,
    transitions,
)
from services.sim.scenario import Scenario
from services.sim.section_landing import limited_coverage, section_strips, worked_fraction
from services.sim.sections import SectionStates, run_section_states
from services.sim.world import World, build_world, driving
from vehicle import Gnss, SpeedSensor

SPEED_SENSOR_SEED_OFFSET = 1  # the speed sensor's noise is seeded apart from the GNSS noise


def cells_in_field(grid: Grid, polygon) -> np.ndarray:
    """Boolean (rows, cols): cells whose centre (`maps.Grid.cell_centres`) lies inside the polygon."""
    import shapely

    x, y = grid.cell_centres()
    return shapely.contains_xy(polygon, x[None, :], y[:, None])


def check_world(world: World, in_field: np.ndarray | None = None) -> MachineCheck:
    """Whether the scenario's machine can apply its map at its working speeds (`limits.machine_check`
    over the prescription's cells inside the field)."""
    sc = world.scenario
    if in_field is None:
        in_field = cells_in_field(world.grid, world.field.polygon)
    return machine_check(world.grid.rates_kg_ha[in_field], working_speeds(sc.tractor), sc.implement)


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
    sections: SectionStates  # gates per tick and section, section widths and offsets, passes
    worked_fraction: np.ndarray  # (rows, cols): share of each cell the plan's working width swept
    limited_fraction: np.ndarray  # (rows, cols): share of each cell covered by product metered at a
    #                               clipped target
    overlap_metrics: OverlapMetrics
    limit_metrics: LimitMetrics
    machine_check: MachineCheck
    # The error split's reference meters' figures (`services.sim.error_split.reference_figures`),
    # when the run computed them beside its accounting; None: computed when asked for.
    reference_figures: list[MapMetrics] | None = None


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
    with driving(scenario, world.path) as driver:
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
    clock = time.perf_counter()
    wall0 = clock - sum(drive.stage_s.values())   # as if the drive had run just now
    core = ControlCore(world.grid, scenario, world.field.polygon, world.path)
    control = core.run_track(drive.measured_x_m, drive.measured_y_m, track["heading_rad"],
                             drive.measured_speed_m_s, track["implement_on"], track["s_m"], progress)
    stage = dict(drive.stage_s, control_s=time.perf_counter() - clock)
    measured = (drive.measured_x_m, drive.measured_y_m, drive.measured_speed_m_s)
    return accounted(world, track, measured, control, stage, wall0, drive.started_unix)


def accounted(world: World, track: dict, measured: tuple, control: dict, stage_s: dict, wall0: float,
              started_unix: float) -> RunResult:
    """The `RunResult` of a driven and controlled track: `account` for it, its time in
    ``stage_s["metrics_s"]``, the summary's wall time counted from `wall0` (`time.perf_counter`).

    `measured` holds the measured x, y (m) and ground speed (m/s) per tick."""
    clock = time.perf_counter()
    summary, rest = account(world, track, control, wall0)
    stage = dict(stage_s, metrics_s=time.perf_counter() - clock)
    summary["wall_time_s"] = time.perf_counter() - wall0
    summary["realtime_factor"] = summary["sim_time_s"] / summary["wall_time_s"]
    summary["stage_s"] = stage
    x_m, y_m, speed_m_s = measured
    return RunResult(world=world, track=track, measured_x_m=x_m, measured_y_m=y_m,
                     measured_speed_m_s=speed_m_s, control=control, stage_s=stage, summary=summary,
                     started_unix=started_unix, **rest)


def sensors(scenario: Scenario) -> tuple[Gnss, SpeedSensor]:
    """The GNSS receiver and the ground-speed sensor the controller reads, seeded from the scenario."""
    return (Gnss(scenario.gnss, seed=scenario.seed),
            SpeedSensor(scenario.speed_sensor, seed=scenario.seed + SPEED_SENSOR_SEED_OFFSET))


def measure(scenario: Scenario, track: dict):
    """Measured x, y (GNSS) and ground speed (speed sensor) over a whole true track."""
    gnss, speed = sensors(scenario)
    x, y = gnss.measure(track["time_s"], track["x_m"], track["y_m"])
    return x, y, speed.measure(track["time_s"], track["speed_m_s"])


def summarize(world: World, track: dict, landing: Landing, parts: tuple, check: MachineCheck,
              wall0: float) -> dict:
    """The summary of a run from its figures (`metrics.summary`): `parts` are the figures' dataclasses
    (`MapMetrics`, `TransitionMetrics`, `OverlapMetrics`, `LimitMetrics`), `check` the machine check;
    ``realtime_factor`` is left 0 for the caller, who knows its wall time."""
    scenario, implement = world.scenario, world.scenario.implement
    n = len(track["time_s"])
    figures = {
        **{k: v for part in parts for k, v in dataclasses.asdict(part).items()},
        "field_area_ha": world.field.area_ha,
        "sim_time_s": n * scenario.timing.control_period_s,
        "wall_time_s": time.perf_counter() - wall0,
        "ticks": n,
        "realtime_factor": 0.0,  # the caller knows its wall time
        "path_length_m": float(landing.distance_m[-1]) if n else 0.0,
        "sections": implement.sections,
        "section_widths_m": [float(w) for w in implement.section_widths],
        "max_speed_m_s": check.max_speed_m_s,
    }
    return metrics.summary(scenario.name, scenario.seed, figures)


def account(world: World, track: dict, control: dict, wall0: float):
    """Land each section's product, build the as-applied raster and compute the summary.

    `control` holds at least ``metered_kg``, ``width_on_m``, ``target_shaft_rpm`` and ``sections_on``
    (`services.sim.core.CONTROL_KEYS`; ``sections_commanded`` too from `vrsim run`): what `vrsim run`
    computes and what the monitor rebuilds from its records. ``track["tick"]``, when given, numbers
    the ticks the arrays hold: a record with gaps (the monitor's after it was down) lands each stretch
    on its own (no strip joins across a gap); ``ticks`` and ``sim_time_s`` count what is there.
    """
    scenario, grid = world.scenario, world.grid
    implement, timing = scenario.implement, scenario.timing
    delay_s, period_s = implement.delivery_delay_s, timing.control_period_s
    metered, width_on = control["metered_kg"], control["width_on_m"]
    states = run_section_states(track, control, implement)
    landing = land(grid, track, metered, width_on, delay_s, period_s)
    cell_m = min(grid.cell_size)
    acc = AsApplied(grid)
    section_strips(track, metered, states, delay_s, period_s, cell_m).add_to(acc)
    in_field = cells_in_field(grid, world.field.polygon)
    cell_w, cell_h = grid.cell_size
    cover = acc.coverage_fraction
    mm = map_metrics(grid.rates_kg_ha, acc.applied_kg_ha, cover, in_field,
                     abs(cell_w * cell_h) / 1e4, float(metered.sum()), acc.outside_kg)
    tm = transitions(track["time_s"], landing.distance_m, landing.prescribed_kg_ha, landing.applied_kg_ha,
                     np.asarray(track["implement_on"], bool))
    worked = worked_fraction(track, implement.width_m, grid)
    om = overlap_metrics(cover, acc.overlap_fraction, acc.overlap_kg, worked, in_field)
    limited = implement.shaft_limited(control["target_shaft_rpm"]) & (width_on > 0)
    limited_cover = limited_coverage(track, metered[:, None], states, limited, delay_s, period_s, cell_m,
                                     grid)[0]
    lm = limit_metrics(limited, width_on > 0, limited_cover, cover, in_field)
    check = check_world(world, in_field)
    summary = summarize(world, track, landing, (mm, tm, om, lm), check, wall0)
    rest = dict(landing=landing, as_applied=acc, in_field=in_field, map_metrics=mm, transition_metrics=tm,
                sections=states, worked_fraction=worked, limited_fraction=limited_cover, overlap_metrics=om,
                limit_metrics=lm, machine_check=check)
    return summary, rest
