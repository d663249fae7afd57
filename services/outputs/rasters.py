"""as_applied.tif and error.tif: applied kg/ha and applied minus prescribed, GeoTIFF on the
prescription's grid."""

from __future__ import annotations

from dataclasses import replace

from maps import write_map
from services.sim.run import RunResult


def write_rasters(result: RunResult, as_applied_path: str, error_path: str) -> None:
    """Write the applied rate and its error against the prescription (kg/ha) as GeoTIFFs."""
    grid = result.world.grid
    applied = result.as_applied.applied_kg_ha
    write_map(replace(grid, rates_kg_ha=applied, product="as-applied"), as_applied_path)
    write_map(replace(grid, rates_kg_ha=applied - grid.rates_kg_ha, product="applied minus prescribed"),
              error_path)
