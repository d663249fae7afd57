"""The error of a run split into its causes: geometry and section control, spread pattern, machine
limits, calibration, metering.

The target shaft speed of every tick, the sections' gates and where product lands do not depend on
the meter (nothing feeds back into them), so the same run is re-landed with three reference meters
whose shafts turn at exactly a given speed each control period (no PID, no plant, no delay). A
reference meter is the run's machine kind (`services.sim.machines`) with each of its metering drives
so turned, its product landing through the kind's own plan (a drive per section: each section's
strip carries its own drive's product):

1. *geometry and section control*: the shaft at the speed the map asks for, unclipped (as if the
   shaft had no speed range). What is left is where and when product lands: the look-ahead,
   section switching and its latencies, overlap and skips, speed changing within the delivery
   delay, a single meter sharing product by width in curves (a drive per section: each drive at its
   own section's rate and, with turn compensation, its own ground speed); its product laid as
   rectangular strips of the sections (`StripPlan`, shared by width), whatever the machine;
   *spread pattern*: the same drives' product landing through the machine's own footprint (a
   spinner's thrown pattern, its sides cut at the boundary); the difference to the strips is what the
   pattern alone costs against rectangular strips at the same driving width (zero for kinds that lay
   strips: their plan is the strips);
2. *machine limits*: the shaft at the target clipped to ``[shaft_rpm_min, shaft_rpm_max]``: the
   ``ideal`` controller kind, metering the configured ``kg_per_rev`` per revolution exactly; the
   difference to the spread pattern's reference;
3. *calibration*: the same shaft, metering what the product really gives per revolution (its true
   constant and its flow variability, `vehicle.product`): what the terminal's wrong constant and the
   uneven flow alone cost; the difference to 2 (zero for a product with neither);
4. *metering*: the run's own controller and plant; the difference to 3.

Each figure (mass balance, mean absolute error) telescopes: the five contributions add up to the
run's figure exactly. A contribution can be negative: a cause can cancel part of another (an
under-applying limit against over-application at swath ends, say).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from vrsim.maps import AppliedColumns, ColumnDeposit
from vrsim.services.sim.accounting import cells_in_field, map_figures
from vrsim.services.sim.machines import Machine, machine_for
from vrsim.services.sim.metrics import MapMetrics
from vrsim.services.sim.result import RunResult
from vrsim.services.sim.section_landing import StripPlan, tick_travel_m
from vrsim.services.sim.sections import SectionStates, run_section_states
from vrsim.services.sim.sections.motion import MotionTrend
from vrsim.services.sim.world import World
from vrsim.vehicle.product import metered_kg

CAUSES = ("geometry and section control", "spread pattern", "machine limits", "calibration", "metering")
# The reference meters (`reference_metered_kg`): (shaft clipped to its range, the product's truth).
REFERENCES = ((False, False), (True, False), (True, True))


@dataclass(frozen=True)
class ErrorPart:
    """One cause's contribution to a run's error.

    Attributes
    ----------
    cause : str
        One of `CAUSES`.
    mass_balance_pct : float
        Its contribution to the mass balance, percentage points.
    mae_kg_ha : float
        Its contribution to the mean absolute error over covered cells, kg/ha.
    share_pct : float
        `mae_kg_ha` as a share of the run's mean absolute error, %.
    """

    cause: str
    mass_balance_pct: float
    mae_kg_ha: float
    share_pct: float


def reference_metered_kg(world: World, machine: Machine, states: SectionStates, control: dict, clipped: bool,
                         true_product: bool, start_rev=0.0) -> tuple[np.ndarray, np.ndarray | float]:
    """Product per tick and drive, kg (ticks, drives), of drives whose shafts turn at exactly their
    targets: the run's (clipped to the shaft's range, as the ``ideal`` kind) or, unclipped, the speed
    the map asks for (the machine kind's targets with the range lifted: each drive's rate at its own
    landing point, its own ground speed); metering the configured constant exactly or, with
    `true_product`, what the product really gives per revolution (`ControlCore._metered_kg`'s way),
    its shafts from `start_rev` revolutions on (a run accounted part by part carries it). Returns the
    product and where the shafts then stand (`vehicle.product.metered_kg`)."""
    sc = world.scenario
    period_s = sc.timing.control_period_s
    if clipped:
        rpm = np.asarray(control["drive_target_rpm"], float)
    else:
        rpm = machine.unlimited_targets(np.nan_to_num(control["drive_rate_kg_ha"]), states, sc.product)
    rev = rpm * period_s / 60.0   # in the machine's terms: a shaft's revolutions, a sprayer's metered litres
    if true_product:
        kg, end_rev = metered_kg(rev, machine.kg_per_rev(sc.product), sc.product, sc.seed, start_rev)
        return kg * machine.drive_share, end_rev
    return machine.configured_kg(rev, sc.product) * machine.drive_share, start_rev


def _reference_figures(world: World, track: dict, control: dict, measured_speed_m_s,
                       worked: np.ndarray) -> list[MapMetrics]:
    """The map figures of the three reference meters (see the module docstring) on the run's track
    and sections: what `error_split` adds to the run's own figures, from an in-process run's arrays
    (`vrsim run` deposits the reference meters part by part beside its own product:
    `services.sim.bounded`).

    The references go through the run's machine kind (`services.sim.machines`): each drive's target
    and product, landing through the kind's plan (a drive per section: each section's strip its own
    drive's product). The sensed motion the targets were computed with is the measured speed and the
    track's heading (`MotionTrend`: a drive's own speed in a turn); `worked` is the run's worked share
    of each cell (`Setting.worked_fraction`). The plan is worked out once and
    mapped to the raster once for all meters (`maps.ColumnDeposit`); their figures are the
    accounting's map figures (`services.sim.accounting.map_figures`)."""
    imp, grid, period_s = world.scenario.implement, world.grid, world.scenario.timing.control_period_s
    machine = machine_for(imp, world.field.polygon)
    states = run_section_states(track, control, imp)
    # Only the motion's speed and yaw rate (from the heading) are read by a kind's targets.
    states = dataclasses.replace(states, motion=MotionTrend(period_s).step(
        track["x_m"], track["y_m"], track["heading_rad"], measured_speed_m_s))
    metered = np.stack([reference_metered_kg(world, machine, states, control, *reference)[0]
                        for reference in REFERENCES], axis=-1)      # (ticks, drives, references)
    delay_s, cell_m, tick_m = imp.delivery_delay_s, min(grid.cell_size), tick_travel_m(world.scenario)
    plan = machine.deposition(track, states, delay_s, period_s, cell_m, tick_m=tick_m)
    rasters = _reference_rasters(grid, plan, metered[:, 0] if machine.drives == 1 else metered)
    strips = rasters   # a machine that lays strips: the pattern costs nothing
    if not isinstance(plan, StripPlan):   # the unclipped drives' product as the sections' strips
        as_strips = StripPlan.of(track, states, delay_s, period_s, cell_m, tick_m=tick_m)
        strips = _reference_rasters(grid, as_strips, metered[..., :1].sum(axis=1))
    in_field = cells_in_field(grid, world.field.polygon)
    stages = [(strips, 0), *((rasters, j) for j in range(metered.shape[-1]))]
    return [map_figures(grid, in_field, r.applied_kg_ha[j], r.coverage_fraction[j],
                        float(np.sum(metered[..., j])), float(r.outside_kg[j]), worked) for r, j in stages]


def _reference_rasters(grid, plan, metered_kg: np.ndarray) -> AppliedColumns:
    """The as-applied rasters of the columns `metered_kg` (ticks, n), or (ticks, drives, n) for several
    drives, through the plan's footprint."""
    return ColumnDeposit(grid, plan.footprint()).apply(plan.mass_kg(metered_kg))


def error_split(result: RunResult) -> list[ErrorPart]:
    """The run's mass balance and mean absolute error split into `CAUSES` (see the module docstring);
    the reference meters' figures from ``result.reference_figures`` when the run computed them."""
    references = result.reference_figures or _reference_figures(
        result.world, result.track, result.control, result.measured_speed_m_s,
        result.accounts.setting.worked_fraction)
    stages = [*references, result.accounts.map]
    total_mae = result.accounts.map.mae_kg_ha
    parts, mb0, mae0 = [], 0.0, 0.0
    for cause, m in zip(CAUSES, stages, strict=True):
        mae = m.mae_kg_ha - mae0
        share = 100.0 * mae / total_mae if total_mae > 0 else float("nan")
        parts.append(ErrorPart(cause, m.mass_balance_pct - mb0, mae, share))
        mb0, mae0 = m.mass_balance_pct, m.mae_kg_ha
    return parts
