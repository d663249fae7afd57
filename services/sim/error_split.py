"""The error of a run split into its causes: geometry and section control, spread pattern, machine
limits, calibration, metering.

The target shaft speed of every tick, the sections' gates and where product lands do not depend on
the meter (nothing feeds back into them), so the same run is re-landed with reference meters
whose shafts turn at exactly a given speed each control period (no PID, no plant, no delay):

1. *geometry and section control*: the shaft at the speed the map asks for, unclipped (as if the
   shaft had no speed range). What is left is where and when product lands: the look-ahead,
   section switching and its latencies, overlap and skips, speed changing within the delivery
   delay, a single meter sharing product by width in curves; its product lands as rectangular
   strips of the sections (`StripPlan`), whatever the machine;
   *spread pattern*: the same meter's product landing through the machine's own footprint
   (`services.sim.machines.Machine.deposition`: a spinner's thrown pattern), each drive at the
   run's target for it (a spinner's cut side meters less) scaled by the unclipped over the clipped
   machine-level speed; the difference to the strips is what the pattern alone costs against
   rectangular strips at the same driving width (zero for kinds that lay strips); the references
   below land through the machine's footprint too, each drive at the run's target;
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

from dataclasses import dataclass

import numpy as np

from maps import AppliedColumns, ColumnDeposit
from services.sim.accounting import cells_in_field, map_figures
from services.sim.machines import Machine, machine_for
from services.sim.metrics import MapMetrics
from services.sim.run import RunResult
from services.sim.section_landing import StripPlan
from services.sim.sections import run_section_states
from services.sim.world import World
from vehicle.product import metered_kg

CAUSES = ("geometry and section control", "spread pattern", "machine limits", "calibration", "metering")
# The reference meters (`_reference_metered_kg`): (shaft clipped to its range, the product's truth).
_REFERENCES = ((False, False), (True, False), (True, True))


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


def _reference_rpm(world: World, control: dict, measured_speed_m_s, clipped: bool) -> np.ndarray:
    """The machine-level shaft speed of a reference meter per tick, rpm: the run's target (clipped to
    the shaft's range, as the ``ideal`` kind) or, unclipped, the speed the map asks for."""
    if clipped:
        return np.asarray(control["target_shaft_rpm"])
    width_on = control["width_on_m"]
    rate = np.nan_to_num(control["prescribed_kg_ha"])
    wanted = world.scenario.implement.target_shaft_rpm(rate, measured_speed_m_s, width_on)
    return np.where(width_on > 0, np.maximum(wanted, 0.0), 0.0)


def _reference_metered_kg(world: World, rpm: np.ndarray, true_product: bool) -> np.ndarray:
    """Product per tick of a meter whose shaft turns at exactly `rpm`: metering the configured
    constant exactly or, with `true_product`, what the product really gives per revolution."""
    sc = world.scenario
    imp, period_s = sc.implement, sc.timing.control_period_s
    if true_product:
        return metered_kg(rpm * period_s / 60.0, imp.kg_per_rev, sc.product, sc.seed)[0]
    return imp.mass_kg(rpm * period_s / 60.0)


def reference_figures(world: World, track: dict, control: dict, measured_speed_m_s) -> list[MapMetrics]:
    """The map figures of the reference meters (see the module docstring) on the run's track and
    sections: what `error_split` adds to the run's own figures. A function of the run's drive and
    control alone, so `vrsim run` computes it beside the run's accounting (`services.sim.streamed`).

    The strips and the machine's footprint lie where the run's did, whatever they carry, so their
    geometry is worked out once (`StripPlan`, `Machine.deposition`) and mapped to the raster once for
    all meters (`maps.ColumnDeposit`); their figures are the accounting's map figures
    (`services.sim.accounting.map_figures`)."""
    imp, grid = world.scenario.implement, world.grid
    rpm = {clipped: _reference_rpm(world, control, measured_speed_m_s, clipped) for clipped in (False, True)}
    metered = np.column_stack([_reference_metered_kg(world, rpm[clipped], true_product)
                               for clipped, true_product in _REFERENCES])
    states = run_section_states(track, control, imp)
    delay_s, period_s = imp.delivery_delay_s, world.scenario.timing.control_period_s
    cell_m = min(grid.cell_size)
    machine = machine_for(imp, world.field.polygon)
    thrown = machine.deposition(track, states, delay_s, period_s, cell_m)
    product = _per_drive(machine, control, metered, rpm[False])
    rasters = _reference_rasters(grid, thrown, product)
    totals = product.reshape(len(product), -1, metered.shape[1]).sum(axis=(0, 1))
    strips, strips_kg = rasters, totals[0]   # a machine that lays strips: the pattern costs nothing
    if not isinstance(thrown, StripPlan):
        plan = StripPlan.of(track, states, delay_s, period_s, cell_m)
        strips, strips_kg = _reference_rasters(grid, plan, metered[:, :1]), metered[:, 0].sum()
    in_field = cells_in_field(grid, world.field.polygon)
    stages = [(strips, 0, strips_kg), *((rasters, j, kg) for j, kg in enumerate(totals))]
    return [map_figures(grid, in_field, r.applied_kg_ha[j], r.coverage_fraction[j], float(kg),
                        float(r.outside_kg[j])) for r, j, kg in stages]


def _per_drive(machine: Machine, control: dict, metered_kg: np.ndarray,
               unclipped_rpm: np.ndarray) -> np.ndarray:
    """The reference meters' product per tick (ticks, m) in the machine's deposition terms: as it is
    for one drive, shape (ticks, m); for several, each drive at the run's own target for it (its
    rate at its landing point, its speed, a spinner's cut side), times what the reference's shaft
    speed is over the run's machine-level one (`Machine.combined`: the clipped references' are the
    run's; the unclipped one's is the speed the map asks for over that speed clipped), shape
    (ticks, drives, m)."""
    if machine.drives == 1:
        return metered_kg
    drive_rpm = np.asarray(control["drive_target_rpm"]) * machine.drive_share
    clipped = np.asarray(control["target_shaft_rpm"])
    speed = np.column_stack([machine.implement.clip_shaft_rpm(unclipped_rpm),
                             *[clipped] * (metered_kg.shape[1] - 1)])
    per_rpm = np.divide(metered_kg, speed, out=np.zeros(metered_kg.shape), where=speed > 0)
    return drive_rpm[:, :, None] * per_rpm[:, None, :]


def _reference_rasters(grid, plan, metered_kg: np.ndarray) -> AppliedColumns:
    """The as-applied rasters of the columns `metered_kg` (ticks[, drives], n) through the plan's
    footprint."""
    return ColumnDeposit(grid, plan.footprint()).apply(plan.mass_kg(metered_kg))


def error_split(result: RunResult) -> list[ErrorPart]:
    """The run's mass balance and mean absolute error split into `CAUSES` (see the module docstring);
    the reference meters' figures from ``result.reference_figures`` when the run computed them."""
    references = result.reference_figures or reference_figures(result.world, result.track, result.control,
                                                               result.measured_speed_m_s)
    stages = [*references, result.accounts.map]
    total_mae = result.accounts.map.mae_kg_ha
    parts, mb0, mae0 = [], 0.0, 0.0
    for cause, m in zip(CAUSES, stages, strict=True):
        mae = m.mae_kg_ha - mae0
        share = 100.0 * mae / total_mae if total_mae > 0 else float("nan")
        parts.append(ErrorPart(cause, m.mass_balance_pct - mb0, mae, share))
        mb0, mae0 = m.mass_balance_pct, m.mae_kg_ha
    return parts
