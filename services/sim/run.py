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
import functools
import time
from dataclasses import dataclass, field

import numpy as np

from common import ScenarioError, files
from controller import ControllerConfig
from maps import AsApplied, Grid
from services.sim import ticks
from services.sim.accounting import (
    Accounts,
    Deposit,
    Setting,
    StageTimer,
    account,
    cells_in_field,
    check_world,
)
from services.sim.aslog import run_point_log
from services.sim.core import ControlCore
from services.sim.display import run_summary
from services.sim.kept import Kept, PathPoints, SeriesWindow
from services.sim.landing import Landing, land
from services.sim.limits import MachineCheck
from services.sim.machines import Machine, machine_for
from services.sim.metrics import LimitMetrics, MapMetrics, OverlapMetrics
from services.sim.resolve import as_run
from services.sim.scenario import Scenario
from services.sim.section_landing import limited_coverage, tick_travel_m
from services.sim.sections import SectionStates, run_section_states
from services.sim.transitions import TransitionMetrics
from services.sim.world import World, build_world, driving
from vehicle import Gnss, SpeedSensor

# `cells_in_field` and `check_world` are the accounting's; `vrsim run --check` and the benchmarks
# import them from here, with the run's other public names.
__all__ = ["Drive", "RunResult", "accounted", "as_applied", "cells_in_field", "check_world",
           "control_and_account", "drive", "measure", "run", "sensors", "start_up"]

SPEED_SENSOR_SEED_OFFSET = 1  # the speed sensor's noise is seeded apart from the GNSS noise
# Memory the in-process run keeps per control tick: ~35 float64 arrays (the track, the sensors, the
# targets, the loop's outputs, the landing) plus temporaries of the vectorized stages.
ARRAY_BYTES_PER_TICK = 400


@dataclass
class RunResult:
    """What a run measured and its accounts: the track and what the sensors read on it, the control
    loop's arrays, the sections' gates, the as-applied raster and the figures (``summary``, from
    `services.sim.metrics.METRICS` over `accounts`; callers add their own keys, such as ``out_dir``).
    The world, the track, where product landed and the field's cells are the accounts' `Setting`'s.

    Per tick (arrays of shape (ticks,), 50 ms ticks by default; docs/api.md lists every attribute):
    ``track`` (dict: the true path), ``measured_*`` (the sensors), ``control`` (dict keyed as
    `services.sim.core.CONTROL_KEYS`: the controller's look-ahead point and rate, target and actual
    shaft speed, current, metered kg, open width, the gates), ``landing`` (`services.sim.landing.
    Landing`: where each tick's product landed, the prescription there and the applied rate). One
    table of them all: `to_pandas` (`services.sim.ticks.tick_columns`).

    NaN in the per-tick rates: ``landing.applied_kg_ha`` (and the table's ``applied_kg_ha``) is a
    tick's metered kg over the strip its open sections covered, so it is NaN where no section is open
    or the strip is under 1 cm: with the implement lifted (turns, headland, the way to the first
    pass), with every section closed over covered ground, at a standstill (13.6 % of the default
    run's ticks: 12.8 % lifted, 0.8 % all sections closed). ``landing.prescribed_kg_ha`` and
    ``control["prescribed_kg_ha"]`` are NaN off the map. The run's figures (``summary``) are over the
    as-applied raster's cells, not over these ticks.
    """

    measured_x_m: np.ndarray
    measured_y_m: np.ndarray
    measured_speed_m_s: np.ndarray
    control: dict
    sections: SectionStates  # gates per tick and section, section widths and offsets, passes
    as_applied: AsApplied
    accounts: Accounts
    started_unix: float  # when the run (or the services run it was rebuilt from) started, Unix time
    # The error split's reference meters' figures (`services.sim.error_split`),
    # when the run computed them beside its accounting; None: computed when asked for.
    reference_figures: list[MapMetrics] | None = None
    # What a run accounted part by part (`services.sim.bounded`) kept for its outputs; None: the
    # in-process run, whose arrays give them (`kept`).
    kept_parts: Kept | None = None
    summary: dict = field(init=False)

    def __post_init__(self):
        self.summary = run_summary(self.accounts)   # and ``units``, the system its figures are shown in

    @property
    def world(self) -> World:
        return self.accounts.setting.world

    @property
    def bounded(self) -> bool:
        """Accounted part by part (`services.sim.bounded`, what `vrsim run` does): no per-tick arrays
        (``track``, ``control``, ``landing``, the measured arrays and ``sections`` are None); the track
        was written as it went, and `kept` holds what the other outputs need."""
        return self.kept_parts is not None

    @functools.cached_property
    def kept(self) -> Kept:
        """The path points, timeseries.png's window and the as-applied log (`services.sim.kept`)."""
        if self.kept_parts is not None:
            return self.kept_parts
        track, landing, control = self.track, self.landing, self.control
        path = PathPoints.for_ticks(len(track["x_m"]))
        path.add(track["x_m"], track["y_m"])
        series = SeriesWindow()
        series.add({"time_s": track["time_s"], "target_shaft_rpm": control["target_shaft_rpm"],
                    "shaft_rpm": control["shaft_rpm"], "prescribed_kg_ha": landing.prescribed_kg_ha,
                    "applied_kg_ha": landing.applied_kg_ha}, track["implement_on"])
        log = run_point_log(self.world, track, control, landing.applied_kg_ha, self.started_unix,
                            self.world.scenario.output.log_rate_hz)
        return Kept(path.xy(), series.finish(), log)

    @property
    def track(self) -> dict:
        return self.accounts.setting.track

    @property
    def landing(self) -> Landing:
        return self.accounts.setting.landing

    @property
    def in_field(self) -> np.ndarray:
        return self.accounts.setting.in_field

    @property
    def worked_fraction(self) -> np.ndarray:
        """(rows, cols): share of each cell the plan's working width swept."""
        return self.accounts.setting.worked_fraction

    @property
    def limited_fraction(self) -> np.ndarray:
        """(rows, cols): share of each cell covered by product metered at a clipped target."""
        return self.accounts.deposit.limited_coverage

    @property
    def machine_check(self) -> MachineCheck:
        return self.accounts.setting.check

    # The accounts' parts by the names the Python API has documented (README, docs/api.md).
    @property
    def map_metrics(self) -> MapMetrics:
        return self.accounts.map

    @property
    def transition_metrics(self) -> TransitionMetrics:
        return self.accounts.transitions

    @property
    def overlap_metrics(self) -> OverlapMetrics:
        return self.accounts.overlap

    @property
    def limit_metrics(self) -> LimitMetrics:
        return self.accounts.limits

    @property
    def stage_s(self) -> dict:
        return self.accounts.timing.stage_s

    def tick_columns(self) -> dict[str, np.ndarray]:
        """Every per-tick array under one name each, units in the names (`services.sim.ticks.
        tick_columns` lists them); a `VrsimError` for a run accounted part by part (``bounded``)."""
        return ticks.tick_columns(self)

    def to_pandas(self):
        """The per-tick table: a `pandas.DataFrame`, one row per tick (index ``tick``), the columns of
        `tick_columns`. NaN rates: see the class docstring."""
        return ticks.to_pandas(self)


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
    """The `RunResult` of a driven and controlled track: each section's product landed, the as-applied
    raster built and the whole accounted (`services.sim.accounting.account`), in the timer's
    ``metrics_s``; the timer then gives the run's wall time.

    `measured` holds the measured x, y (m) and ground speed (m/s) per tick. `control` holds at least
    ``metered_kg``, ``width_on_m``, ``sections_on``, ``drive_target_rpm`` and ``drive_kg``
    (`services.sim.core.CONTROL_KEYS`; ``sections_commanded`` too from `vrsim run`): what `vrsim run`
    computes and what the monitor rebuilds from its records. ``track["tick"]``, when given, numbers
    the ticks the arrays hold: a record with gaps (the monitor's after it was down) lands each stretch
    on its own (no strip joins across a gap); ``ticks`` and ``sim_time_s`` count what is there.
    """
    implement, period_s = world.scenario.implement, world.scenario.timing.control_period_s
    delay_s, cell_m = implement.delivery_delay_s, min(world.grid.cell_size)
    metered, width_on = control["metered_kg"], control["width_on_m"]
    with timer.stage("metrics_s"):
        states = run_section_states(track, control, implement)
        landing = land(world.grid, track, metered, width_on, delay_s, period_s)
        machine = machine_for(implement, world.field.polygon)
        product_kg, tick_m = machine.deposit_kg(control), tick_travel_m(world.scenario)
        acc = as_applied(world.grid, track, product_kg, states, delay_s, period_s, machine, tick_m)
        owned = _owned_overlap(world.grid, track, product_kg, states, delay_s, period_s, machine,
                              tick_m) or acc
        setting = Setting.of(world, track, control, landing)
        limited_cover = limited_coverage(track, metered[:, None], states, setting.limited, delay_s, period_s,
                                         cell_m, world.grid)[0]
        deposit = Deposit(metered, landing.applied_kg_ha, acc.applied_kg_ha, acc.coverage_fraction,
                          owned.overlap_fraction, owned.overlap_kg, acc.outside_kg, limited_cover)
    accounts, = account(setting, [deposit], [timer])
    x_m, y_m, speed_m_s = measured
    return RunResult(measured_x_m=x_m, measured_y_m=y_m, measured_speed_m_s=speed_m_s, control=control,
                     sections=states, as_applied=acc, accounts=accounts, started_unix=started_unix)


def as_applied(grid: Grid, track: dict, product_kg, states: SectionStates, delay_s: float,
               period_s: float, machine: Machine, tick_m: float | None = None) -> AsApplied:
    """The as-applied raster of a run: the machine's product (`Machine.deposit_kg`'s) put on `grid`
    through its footprint (`Machine.deposition`: a strip per section and tick for today's kinds), with
    the passes (strips cut by a tick's travel `tick_m`, m: `section_landing.tick_travel_m`)."""
    acc = AsApplied(grid)
    plan = machine.deposition(track, states, delay_s, period_s, min(grid.cell_size), tick_m=tick_m)
    acc.deposit(plan.footprint(), plan.mass_kg(product_kg), pass_index=plan.pass_index)
    return acc


def _owned_overlap(grid: Grid, track: dict, product_kg, states: SectionStates, delay_s: float,
                  period_s: float, machine: Machine, tick_m: float | None = None) -> AsApplied | None:
    """The product on the ground each pass is set up to own (`Machine.ownership`), whose overlap is
    the run's overlap figures; None for a machine whose deposition lays nothing beyond it (`as_applied`'s
    raster is that ground). `as_applied`'s parameters."""
    own = machine.ownership(track, states, delay_s, period_s, min(grid.cell_size), tick_m=tick_m)
    if own is None:
        return None
    acc = AsApplied(grid)
    acc.deposit(own.footprint(), own.mass_kg(product_kg), pass_index=own.pass_index)
    return acc


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
