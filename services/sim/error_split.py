"""The error of a run split into its causes: geometry and section control, machine limits, metering.

The target shaft speed of every tick, the sections' gates and where product lands do not depend on
the meter (nothing feeds back into them), so the same run is re-landed with two reference meters
whose shafts turn at exactly a given speed each control period (no PID, no plant, no delay):

1. *geometry and section control*: the shaft at the speed the map asks for, unclipped (as if the
   shaft had no speed range). What is left is where and when product lands: the look-ahead,
   section switching and its latencies, overlap and skips, speed changing within the delivery
   delay, a single meter sharing product by width in curves;
2. *machine limits*: the shaft at the target clipped to ``[shaft_rpm_min, shaft_rpm_max]``: the
   ``ideal`` controller kind; the difference to 1;
3. *metering*: the run's own controller and plant; the difference to 2.

Each figure (mass balance, mean absolute error) telescopes: the three contributions add up to the
run's figure exactly. A contribution can be negative: a cause can cancel part of another (an
under-applying limit against over-application at swath ends, say).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from maps import AppliedColumns, ColumnDeposit
from services.sim.accounting import cells_in_field, map_figures
from services.sim.metrics import MapMetrics
from services.sim.run import RunResult
from services.sim.section_landing import StripPlan, tick_travel_m
from services.sim.sections import run_section_states
from services.sim.world import World

CAUSES = ("geometry and section control", "machine limits", "metering")


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


def reference_metered_kg(world: World, control: dict, measured_speed_m_s, clipped: bool) -> np.ndarray:
    """Product per tick of a meter whose shaft turns at exactly the target: the run's (clipped to
    the shaft's range, as the ``ideal`` kind) or, unclipped, the speed the map asks for."""
    imp, period_s = world.scenario.implement, world.scenario.timing.control_period_s
    if clipped:
        rpm = control["target_shaft_rpm"]
    else:
        width_on = control["width_on_m"]
        rate = np.nan_to_num(control["prescribed_kg_ha"])
        wanted = imp.target_shaft_rpm(rate, measured_speed_m_s, width_on)
        rpm = np.where(width_on > 0, np.maximum(wanted, 0.0), 0.0)
    return imp.mass_kg(rpm * period_s / 60.0)


def _reference_figures(world: World, track: dict, control: dict, measured_speed_m_s) -> list[MapMetrics]:
    """The map figures of the two reference meters (unclipped, clipped: see the module docstring) on
    the run's track and sections: what `error_split` adds to the run's own figures, from an in-process
    run's arrays (`vrsim run` deposits the reference meters part by part beside its own product:
    `services.sim.bounded`).

    The strips lie where the run's did, whatever they carry, so their geometry is worked out once
    (`StripPlan`) and mapped to the raster once for both meters (`maps.ColumnDeposit`); their figures are
    the accounting's map figures (`services.sim.accounting.map_figures`)."""
    imp, grid = world.scenario.implement, world.grid
    metered = np.column_stack([reference_metered_kg(world, control, measured_speed_m_s, clipped)
                               for clipped in (False, True)])
    plan = StripPlan.of(track, run_section_states(track, control, imp), imp.delivery_delay_s,
                        world.scenario.timing.control_period_s, min(grid.cell_size),
                        tick_m=tick_travel_m(world.scenario))
    rasters = _reference_rasters(grid, plan, metered)
    in_field = cells_in_field(grid, world.field.polygon)
    applied_kg_ha = rasters.applied_kg_ha
    return [map_figures(grid, in_field, applied_kg_ha[j], rasters.coverage_fraction[j],
                        float(np.sum(metered[:, j])), float(rasters.outside_kg[j]))
            for j in range(metered.shape[1])]


def _reference_rasters(grid, plan: StripPlan, metered_kg: np.ndarray) -> AppliedColumns:
    """The as-applied rasters of the columns `metered_kg` (ticks, n) along the plan's strips."""
    return ColumnDeposit(grid, plan.strips.footprint()).apply(plan.mass_kg(metered_kg))


def error_split(result: RunResult) -> list[ErrorPart]:
    """The run's mass balance and mean absolute error split into `CAUSES` (see the module docstring);
    the reference meters' figures from ``result.reference_figures`` when the run computed them."""
    references = result.reference_figures or _reference_figures(result.world, result.track, result.control,
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
