"""Controller variants over one drive, as one batch: the fast path of sweeps and `vrsim tune`.

A controller does not change the drive (SUMO track, sensor readings), nor the stage-1 targets while
the look-ahead is the same (landing point, prescription there, sections, target shaft speed), nor
the geometry of where product lands (strips of the sections that are on). `run_variants` computes
those once and then

1. runs the variants' loops together on the shared targets (`controller.build_variant_loops`: the
   PID family on its lifted-matrix fast path, one loop per variant and metering drive with its own
   gains; other kinds one after another);
2. lands every variant's metered product at once: the applied rate per tick is a column per variant,
   the masses of the machine's deposition (`services.sim.machines.Machine.deposition`: the joined
   strips) too, and the as-applied rasters come from one sparse map from its items to cells
   (`maps.ColumnDeposit`) applied to all mass columns (a drive per section: each section's strips
   from its own drive's columns);
3. accounts for each variant's deposit with the run's own accounting (`services.sim.accounting`).

The controller-free work (the targets, the strips and their sparse map, the landing geometry, the
worked area, the rate steps, the machine check) is done once for all the variants of one look-ahead,
however many batches of `VARIANT_CHUNK` they make (`_Shared`).

Each summary equals `control_and_account(drive, cfg).summary` to rounding (tested to 1e-9 relative),
but for the wall times: a variant's ``control_s`` and ``metrics_s`` are its share of its batch's
(and its raster chunk's) and of the shared work's (each time over the variants it served), on top
of the drive's stages; its wall time is their sum.

Variants whose look-ahead differs form separate batches (their targets differ); a variant with the
look-ahead tune on (``look_ahead_tune > 0``: its targets depend on its own loop) runs alone through
`control_and_account`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError, ScenarioError
from vrsim.controller import ControllerConfig, build_variant_loops
from vrsim.maps import AppliedColumns, ColumnDeposit
from vrsim.services.sim.accounting import Deposit, Setting, StageTimer, account
from vrsim.services.sim.core import OPENING_KEY, RUN_CHUNK, ControlCore, context_track, machine_plant
from vrsim.services.sim.display import run_summary
from vrsim.services.sim.landing import applied_rate_kg_ha, land
from vrsim.services.sim.look_ahead import initial_look_ahead_s
from vrsim.services.sim.run import Drive, control_and_account
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.section_landing import LimitedStrips, StripPlan, tick_travel_m
from vrsim.services.sim.sections import run_section_states

# Variants run as one loop batch: more cut the loop's Python work per variant (256: about a quarter
# less than 128), and hold more (their ticks x variants of floats, 0.36 GB for 256 on the default
# scenario's 177,000 ticks).
VARIANT_CHUNK = 256
RASTER_CHUNK = 32    # variants whose rasters and applied rates are held at once (n x sub-cells, n x ticks)


def run_variants(drive: Drive, controllers: Sequence[ControllerConfig]) -> list[dict]:
    """The summary of each controller over `drive`, computed as a batch (see the module docstring).

    Parameters
    ----------
    drive : Drive
        From `services.sim.run.drive` (not changed).
    controllers : sequence of ControllerConfig

    Returns
    -------
    list of dict
        One summary per controller, in order: the keys of `vrsim run --json` (`control_and_account`).

    Raises
    ------
    ScenarioError
        A controller the run refuses (as `control_and_account` would).
    """
    scenario = drive.world.scenario
    out: list[dict | None] = [None] * len(controllers)
    batches: dict[float, list[int]] = {}
    for i, cfg in enumerate(controllers):
        if cfg.look_ahead_tune > 0:
            out[i] = control_and_account(drive, cfg).summary
            continue
        sc = dataclasses.replace(scenario, controller=cfg)
        try:
            look_ahead = initial_look_ahead_s(sc, machine_plant(sc, drive.world.grid))
        except ControllerError as exc:
            raise ScenarioError(f"{scenario.source}: [controller] {exc}") from None
        batches.setdefault(look_ahead, []).append(i)
    for idx in batches.values():
        shared = _Shared.of(drive, dataclasses.replace(scenario, controller=controllers[idx[0]]), len(idx))
        for lo in range(0, len(idx), VARIANT_CHUNK):
            part = idx[lo:lo + VARIANT_CHUNK]
            for i, summary in zip(part, _batch(shared, [controllers[i] for i in part]), strict=True):
                out[i] = summary
    return out


@dataclass
class _Shared:
    """What the variants of one look-ahead share: the drive, stage 1's targets and the product's
    geometry (the accounting's `Setting`, with its landing geometry, and the strips: everything
    `services.sim.run.accounted` computes that the metered kg do not change). The setting's world is
    the first variant's (the variants differ in their controller only, which no figure reads)."""

    drive: Drive
    scenario: Scenario
    rec: dict                 # stage 1 per tick (`ControlCore.targets`)
    core: ControlCore
    setting: Setting          # its landing's applied rates are each variant's own
    plan: StripPlan           # the machine's deposition (`services.sim.machines.Machine.deposition`)
    strip_map: ColumnDeposit
    limited_strips: LimitedStrips
    control_s: float          # each variant's share of the shared stage 1
    metrics_s: float          # ... and of the shared geometry
    owned: tuple | None = None   # (plan, its ColumnDeposit) of `Machine.ownership`; None: `plan`'s ground

    @classmethod
    def of(cls, drive: Drive, scenario: Scenario, variants: int) -> _Shared:
        clock = time.perf_counter()
        rec, core = _targets(drive, scenario)
        control_s = time.perf_counter() - clock
        clock = time.perf_counter()
        world, track = dataclasses.replace(drive.world, scenario=scenario), drive.track
        grid, implement, timing = world.grid, scenario.implement, scenario.timing
        delay_s, period_s, cell_m = implement.delivery_delay_s, timing.control_period_s, min(grid.cell_size)
        width_on = rec["width_on_m"]
        states = run_section_states(track, rec, implement)
        landing = land(grid, track, np.zeros(len(width_on)), width_on, delay_s, period_s)
        setting = Setting.of(world, track, rec, landing)
        plan = core.machine.deposition(track, states, delay_s, period_s, cell_m,
                                       tick_m=tick_travel_m(scenario))
        own = core.machine.ownership(track, states, delay_s, period_s, cell_m, tick_m=tick_travel_m(scenario))
        shared = cls(drive, scenario, rec, core, setting, plan, _strip_map(grid, plan),
                     LimitedStrips.of(track, states, setting.limited, delay_s, period_s, cell_m, grid),
                     control_s / variants, 0.0, None if own is None else (own, _strip_map(grid, own)))
        shared.metrics_s = (time.perf_counter() - clock) / variants
        return shared


def _strip_map(grid, plan: StripPlan) -> ColumnDeposit:
    """The sparse map from the plan's items (with their passes) to the grid's cells."""
    return ColumnDeposit(grid, plan.footprint(), pass_index=plan.pass_index)


def _batch(shared: _Shared, cfgs: list[ControllerConfig]) -> list[dict]:
    """Variants of one look-ahead: one loop batch on the shared targets (a loop per variant and
    metering drive), then their accounts."""
    scenario, rec, drive = shared.scenario, shared.rec, shared.drive
    clock = time.perf_counter()
    timing, drives = scenario.timing, shared.core.machine.drives
    try:   # column v * drives + d: variant v's drive d
        loops = build_variant_loops(shared.core.plant, [cfg for cfg in cfgs for _ in range(drives)],
                                    timing.control_period_s, timing.plant_step_s)
    except ControllerError as exc:
        raise ScenarioError(f"{scenario.source}: [controller] {exc}") from None
    ticks = len(rec["target_shaft_rpm"])
    metered = np.empty((ticks, len(cfgs) * drives))
    for idx, loop in loops:
        which = np.asarray(idx) % drives
        # Each variant's shafts start where the run's did (`vehicle.product`: the flow factors).
        shared.core.meter_rev = np.zeros(1)
        for lo in range(0, ticks, RUN_CHUNK):   # bounded memory: the loop records 4 outputs per tick
            part = slice(lo, lo + RUN_CHUNK)
            targets = _loop_targets(rec["drive_target_rpm"][part], which, loop.n)
            context = context_track(rec, part, which)
            gain = rec[OPENING_KEY][part] if OPENING_KEY in rec else None
            metered[part, idx] = shared.core._metered_kg(loop.run(targets, context=context).shaft_rev,
                                                         rec["drive_open"][part][:, which], which, gain)
    control_s = time.perf_counter() - clock
    # A variant's wall time is the sum of its shares of the work done for it.
    timers = [StageTimer({**drive.stage_s, "control_s": shared.control_s + control_s / len(cfgs),
                          "metrics_s": shared.metrics_s}, shares=True) for _ in cfgs]
    return _account(shared, metered.reshape(ticks, len(cfgs), drives).transpose(0, 2, 1), timers)


def _loop_targets(drive_target_rpm: np.ndarray, which: np.ndarray, n: int) -> np.ndarray:
    """The targets (ticks, n) of a loop batch whose loops run drives `which` (one drive: the one
    target as a broadcast view, which the loops take without a copy per loop)."""
    if drive_target_rpm.shape[1] == 1:
        target = drive_target_rpm[:, 0]
        return np.broadcast_to(target[:, None], (len(target), n)) if n > 1 else target
    return drive_target_rpm[:, which]


def _targets(drive: Drive, scenario) -> tuple[dict, ControlCore]:
    """Stage 1 over the drive, in `ControlCore.run_track`'s chunks (the policy's and the section
    switch's memory carried). The sections do not depend on the controller (the switch reads the
    sensed track and its own coverage map, never the meter), so one switch serves the batch."""
    world, track = drive.world, drive.track
    core = ControlCore(world.grid, scenario, world.field.polygon, world.path)
    columns = (drive.measured_x_m, drive.measured_y_m, track["heading_rad"], drive.measured_speed_m_s,
               track["implement_on"], track["s_m"])
    n = len(drive.measured_x_m)
    parts = [core.targets(*(np.asarray(a)[lo:lo + RUN_CHUNK] for a in columns))
             for lo in range(0, max(n, 1), RUN_CHUNK)]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, core


def _account(shared: _Shared, drive_kg: np.ndarray, timers: list[StageTimer]) -> list[dict]:
    """The summaries of the mass columns `drive_kg` (ticks x drives x variants): their deposits,
    `RASTER_CHUNK` at a time from the shared strips' sparse map, accounted
    (`services.sim.accounting.account`); each variant's timer gets its share of the work as
    ``metrics_s``."""
    metered = drive_kg[:, 0, :] if drive_kg.shape[1] == 1 else drive_kg.sum(axis=1)
    setting = shared.setting
    width_on_m, strip_length_m = shared.rec["width_on_m"][:, None], setting.landing.strip_length_m[:, None]
    clock = time.perf_counter()
    limited_cover = shared.limited_strips.coverage(metered)
    limited_s = (time.perf_counter() - clock) / len(timers)
    summaries = []
    for lo in range(0, metered.shape[1], RASTER_CHUNK):
        clock = time.perf_counter()
        columns, chunk = metered[:, lo:lo + RASTER_CHUNK], timers[lo:lo + RASTER_CHUNK]
        rasters = _rasters(shared, drive_kg[:, :, lo:lo + RASTER_CHUNK])
        owned = _owned_rasters(shared, drive_kg[:, :, lo:lo + RASTER_CHUNK]) or rasters
        applied, cover = rasters.applied_kg_ha, rasters.coverage_fraction
        # the applied rate per tick, a row per variant (its transitions read it whole)
        rates = applied_rate_kg_ha(columns, width_on_m, strip_length_m).T.copy()
        deposits = [Deposit(columns[:, c], rates[c], applied[c], cover[c], owned.overlap_fraction[c],
                            owned.overlap_kg[c], float(rasters.outside_kg[c]), limited_cover[lo + c])
                    for c in range(len(chunk))]
        share_s = limited_s + (time.perf_counter() - clock) / len(chunk)
        for timer in chunk:
            timer.add("metrics_s", share_s)
        # summed up chunk by chunk: the accounts hold their rasters
        summaries += [run_summary(a) for a in account(setting, deposits, chunk)]
    return summaries


def _rasters(shared: _Shared, drive_kg: np.ndarray) -> AppliedColumns:
    """The as-applied rasters of the mass columns `drive_kg` (ticks, drives, n) along the shared strips."""
    product = drive_kg[:, 0, :] if drive_kg.shape[1] == 1 else drive_kg
    return shared.strip_map.apply(shared.plan.mass_kg(product))


def _owned_rasters(shared: _Shared, drive_kg: np.ndarray) -> AppliedColumns | None:
    """`_rasters` on the ground each pass owns (`Machine.ownership`); None where that is the plan's."""
    if shared.owned is None:
        return None
    plan, strip_map = shared.owned
    return strip_map.apply(plan.mass_kg(drive_kg[:, 0, :] if drive_kg.shape[1] == 1 else drive_kg))
