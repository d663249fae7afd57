"""A run's accounting, once: what its ticks put on the ground becomes its figures (`Accounts`).

Every path that reports a run's figures comes here: a run's one accounting
(`services.sim.bounded.BoundedAccount`: `vrsim run`'s streamed run part by part, the in-process run and
the monitor's report rebuilt from its records the whole track at once, `services.sim.run.accounted`),
controller variants, many mass columns at once (`services.sim.variants`: `account`), and the error
split's reference meters (`map_figures`, the map part alone). The summary is the rows of
`services.sim.metrics.METRICS` read off the `Accounts` (`metrics.summary`): a new figure is a row there
and its formula, nothing else.

The parts:

- `Setting`: what every mass column of one drive shares (the world, the track, where each tick's
  product lands, the field's cells, the worked area, the machine-limited ticks, the machine check);
- `Deposit`: what one mass column put on the ground (the as-applied raster's figures, its applied rate
  per tick at the landing point, where the machine-limited product landed);
- `StageTimer`: the wall time of each stage, read once into the `Timing` of the accounts;
- `account`: figures of deposits in a setting, each column's share of the time in its timer.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from vrsim.common import ScenarioError, VehicleError
from vrsim.maps import Grid
from vrsim.services.sim.landing import M2_PER_HA, Landing
from vrsim.services.sim.limits import MachineCheck, machine_check, working_speeds
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.metric_formulas import (
    LimitMetrics,
    MapMetrics,
    OverlapMetrics,
    limit_metrics,
    map_metrics,
    overlap_metrics,
)
from vrsim.services.sim.section_landing import worked_fraction
from vrsim.services.sim.transitions import TransitionMetrics, rate_steps, transitions
from vrsim.services.sim.world import World


def cells_in_field(grid: Grid, polygon) -> np.ndarray:
    """Boolean (rows, cols): cells whose centre (`maps.Grid.cell_centres`) lies inside the polygon."""
    import shapely

    x, y = grid.cell_centres()
    return shapely.contains_xy(polygon, x[None, :], y[:, None])


def check_world(world: World, in_field: np.ndarray | None = None) -> MachineCheck:
    """Whether the scenario's machine can apply its map at its working speeds (`limits.machine_check`
    over the prescription's cells inside the field, a vector map's read as its zones' rates)."""
    sc, grid = world.scenario, world.grid
    if in_field is None:
        in_field = cells_in_field(grid, world.field.polygon)
    try:
        return machine_check(grid.rates_kg_ha[in_field], working_speeds(sc.tractor), sc.implement,
                             sc.product.density_kg_l, sc.tractor.working_speed_m_s, grid.zone_rates_kg_ha)
    except VehicleError as exc:   # a sprayer's nozzle that cannot apply the map at any speed
        raise ScenarioError(f"{sc.source}: {exc}") from None


@dataclass(frozen=True)
class Timing:
    """Wall time of a run: per stage (``build_s``, ``control_s``, ``metrics_s``, ...) and in all, s."""

    stage_s: dict
    wall_time_s: float


class StageTimer:
    """The wall time of a run's stages, read once into its `Timing` (`timing`).

    Parameters
    ----------
    stage_s : dict, optional
        Stages already timed (a drive's), s.
    started_s : float, optional
        `time.perf_counter` when the run began; default: now less `stage_s` (as if they had just run).
    wall_time_s : float, optional
        The run's wall time when it was not this process's clock (a services run, by its records).
    shares : bool
        The stages are shares of work done for many runs at once (controller variants): the wall time
        is their sum.
    """

    def __init__(self, stage_s: dict | None = None, started_s: float | None = None,
                 wall_time_s: float | None = None, shares: bool = False):
        self.stage_s = dict(stage_s or {})
        self._started_s = time.perf_counter() - sum(self.stage_s.values()) if started_s is None else started_s
        self._wall_time_s = wall_time_s
        self._shares = shares

    @contextmanager
    def stage(self, name: str):
        """Add the time of the ``with`` block to stage `name`."""
        clock = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - clock)

    def add(self, name: str, seconds: float) -> None:
        """Add `seconds` to stage `name` (a new stage comes last)."""
        self.stage_s[name] = self.stage_s.get(name, 0.0) + seconds

    def timing(self) -> Timing:
        """The stages so far and the run's wall time."""
        if self._wall_time_s is not None:
            wall_s = self._wall_time_s
        elif self._shares:
            wall_s = sum(self.stage_s.values())
        else:
            wall_s = time.perf_counter() - self._started_s
        return Timing(dict(self.stage_s), wall_s)


@dataclass(frozen=True)
class Setting:
    """What every mass column over one drive shares (nothing in it depends on the metered product).

    Attributes
    ----------
    world : World
    track : dict or None
        The true track per tick (``track["tick"]``, when given, numbers the ticks: a monitor's record);
        None for a run accounted part by part without its arrays (`services.sim.bounded`, `vrsim
        run`), as are `landing`, `limited`, `applying` and `steps`.
    landing : Landing or None
        Where each tick's product lands (its applied rates are a column's own: `Deposit.rate_kg_ha`).
    in_field : ndarray of bool, shape (rows, cols)
        Cells whose centre lies inside the field.
    worked_fraction : ndarray, shape (rows, cols)
        Share of each cell the plan's working width swept (`section_landing.worked_fraction`).
    limited, applying : ndarray of bool, shape (ticks,)
        Ticks in which any open drive's target shaft speed was clipped to the shaft's range (a drive
        per section: one section's drive alone flags the tick and its product), and ticks with a gate
        open.
    steps : ndarray of int
        The prescription's rate steps under the landing point (`services.sim.transitions.rate_steps`).
    check : MachineCheck
    ticks : int
        Control ticks accounted.
    path_length_m : float
        Length of the landing path (the last tick's distance; 0: no tick), m.
    """

    world: World
    track: dict | None
    landing: Landing | None
    in_field: np.ndarray
    worked_fraction: np.ndarray
    limited: np.ndarray | None
    applying: np.ndarray | None
    steps: np.ndarray | None
    check: MachineCheck
    ticks: int
    path_length_m: float

    @classmethod
    def of(cls, world: World, track: dict, control: dict, landing: Landing) -> Setting:
        """The setting of a drive and its targets (`control`: ``width_on_m``, ``drive_target_rpm``)."""
        grid, implement = world.grid, world.scenario.implement
        in_field = cells_in_field(grid, world.field.polygon)
        applying = control["width_on_m"] > 0
        limited = machine_for(implement).limited(control, world.scenario.product) & applying
        return cls(world, track, landing, in_field, worked_fraction(track, implement.width_m, grid),
                   limited, applying,
                   rate_steps(landing.prescribed_kg_ha, np.asarray(track["implement_on"], bool)),
                   check_world(world, in_field), len(track["time_s"]), float(landing.distance_m[-1:].sum()))


@dataclass(frozen=True)
class Deposit:
    """What one mass column put on the ground.

    Attributes
    ----------
    metered_kg, rate_kg_ha : ndarray, shape (ticks,), or None
        Product through the meter per tick, kg, and its applied rate at the landing point, kg/ha
        (`landing.applied_rate_kg_ha`); None for a run accounted part by part without its arrays
        (`services.sim.bounded`).
    applied_kg_ha, coverage_fraction, overlap_fraction, overlap_kg : ndarray, shape (rows, cols)
        The as-applied raster: product per cell area, the share of each cell product landed on, the
        share more than one pass put product on, and the product beyond the first pass (kg).
    outside_kg : float
        Product that landed off the grid, kg.
    limited_coverage : ndarray, shape (rows, cols)
        Share of each cell that product metered in machine-limited ticks landed on.
    """

    metered_kg: np.ndarray
    rate_kg_ha: np.ndarray
    applied_kg_ha: np.ndarray
    coverage_fraction: np.ndarray
    overlap_fraction: np.ndarray
    overlap_kg: np.ndarray
    outside_kg: float
    limited_coverage: np.ndarray


@dataclass(frozen=True)
class Accounts:
    """A run's accounts: what `services.sim.metrics.METRICS`' rows read their figures from.

    Attributes
    ----------
    setting : Setting
    deposit : Deposit
    map : MapMetrics
    transitions : TransitionMetrics
    overlap : OverlapMetrics
    limits : LimitMetrics
    timing : Timing
    """

    setting: Setting
    deposit: Deposit
    map: MapMetrics
    transitions: TransitionMetrics
    overlap: OverlapMetrics
    limits: LimitMetrics
    timing: Timing


def map_figures(grid: Grid, in_field: np.ndarray, applied_kg_ha, coverage_fraction, metered_kg: float,
                outside_kg: float, worked: np.ndarray) -> MapMetrics:
    """`metrics.map_metrics` of a raster on `grid` (its cells of `maps.Grid.cell_area_m2`); `metered_kg`
    is all product metered, `outside_kg` what landed off the grid, `worked` the plan's worked share of
    each cell (`Setting.worked_fraction`)."""
    return map_metrics(grid.rates_kg_ha, applied_kg_ha, coverage_fraction, in_field,
                       grid.cell_area_m2 / M2_PER_HA, metered_kg, outside_kg, worked_fraction=worked)


def account(setting: Setting, deposits: Sequence[Deposit], timers: Sequence[StageTimer]) -> list[Accounts]:
    """The accounts of each deposit in `setting` (controller variants: many at once).

    Parameters
    ----------
    setting : Setting
    deposits : sequence of Deposit
    timers : sequence of StageTimer
        One per deposit: each gets its share of this call's time as ``metrics_s``, then is read into
        its accounts' `Timing`.
    """
    clock = time.perf_counter()
    parts = [_figures(setting, d) for d in deposits]
    share_s = (time.perf_counter() - clock) / max(len(parts), 1)
    out = []
    for deposit, figures, timer in zip(deposits, parts, timers, strict=True):
        timer.add("metrics_s", share_s)
        out.append(Accounts(setting, deposit, *figures, timing=timer.timing()))
    return out


def _figures(s: Setting, d: Deposit) -> tuple[MapMetrics, TransitionMetrics, OverlapMetrics, LimitMetrics]:
    """The figures of one deposit, by part."""
    cover, landing = d.coverage_fraction, s.landing
    return (map_figures(s.world.grid, s.in_field, d.applied_kg_ha, cover, float(d.metered_kg.sum()),
                        d.outside_kg, s.worked_fraction),
            transitions(s.track["time_s"], landing.distance_m, landing.prescribed_kg_ha, d.rate_kg_ha,
                        np.asarray(s.track["implement_on"], bool), s.steps),
            overlap_metrics(cover, d.overlap_fraction, d.overlap_kg, s.worked_fraction, s.in_field,
                            s.world.grid.rates_kg_ha),
            limit_metrics(s.limited, s.applying, d.limited_coverage, cover, s.in_field))
