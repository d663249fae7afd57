"""The run's GeoTIFFs on the prescription's grid (in the field's UTM zone): prescription.tif, the map
as run; as_applied.tif, the applied rate; error.tif, applied minus prescribed (a signed
difference, tagged so, which `vrsim map` reads as such), all three in the map's own unit
(`maps.write_map`); passes.tif, the number of passes that put product on
each cell. Cells outside the field are nodata in as_applied.tif and error.tif: what lands there is
off-target product (summary.json's off_target_kg), not a rate of the field."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vrsim.common import MapError
from vrsim.maps import write_map
from vrsim.services.sim.run import RunResult


def write_rasters(result: RunResult, prescription_path: str, as_applied_path: str, error_path: str,
                  passes_path: str) -> None:
    """Write the prescription, the applied rate and its error against the prescription (in the map's
    unit), and the pass counts."""
    grid = result.world.grid
    # The deposit's raster, read once by the run (each read of `result.as_applied` sums it again).
    applied = np.where(result.in_field, result.accounts.deposit.applied_kg_ha, np.nan)
    write_map(grid, prescription_path)
    write_map(replace(grid, rates_kg_ha=applied, product="as-applied"), as_applied_path)
    write_map(replace(grid, rates_kg_ha=applied - grid.rates_kg_ha, product="applied minus prescribed",
                      quantity="difference"), error_path)
    _write_passes(result, passes_path)


def _write_passes(result: RunResult, path: str) -> None:
    """passes.tif: per cell, how many passes put product on at least half of it
    (`maps.AsApplied.pass_count`), uint16 on the prescription's grid (0: no product); tagged
    ``unit=passes`` (a count, not a rate: not a `maps.Grid`)."""
    import rasterio
    from rasterio.errors import RasterioError

    grid = result.world.grid
    count = np.minimum(result.as_applied.pass_count, np.iinfo(np.uint16).max).astype(np.uint16)
    profile = dict(driver="GTiff", width=grid.cols, height=grid.rows, count=1, dtype="uint16",
                   crs=grid.crs.to_wkt(), transform=grid.transform, compress="deflate")
    try:
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(count, 1)
            dst.update_tags(unit="passes", quantity="count")
            dst.set_band_description(1, "passes that put product on at least half of the cell")
    except RasterioError as exc:
        raise MapError(f"{path}: cannot write GeoTIFF: {exc}") from None
