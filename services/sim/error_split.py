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

from maps import StripMap
from services.sim.metrics import MapMetrics, map_metrics
from services.sim.run import RunResult
from services.sim.section_landing import StripPlan

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


def reference_metered_kg(result: RunResult, clipped: bool) -> np.ndarray:
    """Product per tick of a meter whose shaft turns at exactly the target: the run's (clipped to
    the shaft's range, as the ``ideal`` kind) or, unclipped, the speed the map asks for."""
    imp, c = result.world.scenario.implement, result.control
    period_s = result.world.scenario.timing.control_period_s
    if clipped:
        rpm = c["target_shaft_rpm"]
    else:
        width_on = c["width_on_m"]
        rate = np.nan_to_num(c["prescribed_kg_ha"])
        wanted = imp.target_shaft_rpm(rate, result.measured_speed_m_s, width_on)
        rpm = np.where(width_on > 0, np.maximum(wanted, 0.0), 0.0)
    return imp.mass_kg(rpm * period_s / 60.0)


def relanded(result: RunResult, metered_kg) -> list[MapMetrics]:
    """The map figures of the run's track and sections with each column of `metered_kg` (ticks x n)
    per tick instead. The strips lie where the run's did, whatever they carry, so their geometry is
    worked out once (`StripPlan`) and mapped to the raster once for all columns (`maps.StripMap`)."""
    world, imp = result.world, result.world.scenario.implement
    grid, metered = world.grid, np.asarray(metered_kg, float)
    plan = StripPlan.of(result.track, result.sections, imp.delivery_delay_s,
                        world.scenario.timing.control_period_s, min(grid.cell_size))
    s = plan.strips
    rasters = StripMap(grid, s.x0_m, s.y0_m, s.x1_m, s.y1_m, s.width_m).apply(plan.mass_kg(metered))
    cell_w, cell_h = grid.cell_size
    return [map_metrics(grid.rates_kg_ha, rasters.applied_kg_ha[j], rasters.coverage_fraction[j],
                        result.in_field, abs(cell_w * cell_h) / 1e4, float(np.sum(metered[:, j])),
                        float(rasters.outside_kg[j]))
            for j in range(metered.shape[1])]


def error_split(result: RunResult) -> list[ErrorPart]:
    """The run's mass balance and mean absolute error split into `CAUSES` (see the module docstring)."""
    references = np.column_stack([reference_metered_kg(result, clipped=False),
                                  reference_metered_kg(result, clipped=True)])
    stages = [*relanded(result, references), result.map_metrics]
    total_mae = result.map_metrics.mae_kg_ha
    parts, mb0, mae0 = [], 0.0, 0.0
    for cause, m in zip(CAUSES, stages, strict=True):
        mae = m.mae_kg_ha - mae0
        share = 100.0 * mae / total_mae if total_mae > 0 else float("nan")
        parts.append(ErrorPart(cause, m.mass_balance_pct - mb0, mae, share))
        mb0, mae0 = m.mass_balance_pct, m.mae_kg_ha
    return parts
