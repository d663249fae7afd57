"""The run's GeoTIFFs on the prescription's grid (in the field's UTM zone): prescription.tif, the map
as run; as_applied.tif, applied kg/ha; error.tif, applied minus prescribed (a signed difference,
tagged so, which `vrsim map` reads as such). Cells outside the field are nodata in the last two: what
lands there is off-target product (summary.json's off_target_kg), not a rate of the field."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from maps import write_map
from services.sim.run import RunResult


def write_rasters(result: RunResult, prescription_path: str, as_applied_path: str, error_path: str) -> None:
    """Write the prescription, the applied rate and its error against the prescription (kg/ha)."""
    grid = result.world.grid
    applied = np.where(result.in_field, result.as_applied.applied_kg_ha, np.nan)
    write_map(grid, prescription_path)
    write_map(replace(grid, rates_kg_ha=applied, product="as-applied"), as_applied_path)
    write_map(replace(grid, rates_kg_ha=applied - grid.rates_kg_ha, product="applied minus prescribed",
                      quantity="difference"), error_path)
