"""Moving a grid between CRSs, and checking that a field and a map overlap."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import rasterio.warp
import shapely
from rasterio.crs import CRS
from rasterio.enums import Resampling

from vrsim.common import MapError, check_positive
from vrsim.maps.crs import WGS84, crs_label, metres_per_unit, transform_xy, transformer
from vrsim.maps.grid import Grid, grid_from_bounds

# Metres per degree of latitude, and of longitude at the equator (WGS84, to 0.1 %: cell sizes only).
M_PER_DEG_LAT = 110_574.0
M_PER_DEG_LON = 111_320.0


def _cell_size_metres(grid: Grid) -> tuple[float, float]:
    """(x, y) cell size in metres; for a lon/lat grid, at its centre latitude."""
    factor = metres_per_unit(grid.crs)
    dx, dy = grid.cell_size
    if factor is not None:
        return dx * factor, dy * factor
    west, south, east, north = grid.bounds
    lat = math.radians(0.5 * (south + north))
    return dx * M_PER_DEG_LON * math.cos(lat), dy * M_PER_DEG_LAT


def reproject_grid(grid: Grid, dst_crs: pyproj.CRS, cell_size_m: float | None) -> Grid:
    """See `Grid.reproject`."""
    if cell_size_m is None:
        cell_size_m = min(_cell_size_metres(grid))
    check_positive(cell_size_m, "reproject: cell_size_m", MapError)
    west, south, east, north = transformer(grid.crs, dst_crs).transform_bounds(*grid.bounds, densify_pts=21)
    if not all(map(math.isfinite, (west, south, east, north))):
        raise MapError(f"reproject: {grid.source or 'grid'} cannot be expressed in {crs_label(dst_crs)}")
    factor = metres_per_unit(dst_crs)
    if factor is None:
        lat = math.radians(0.5 * (south + north))
        size = (cell_size_m / (M_PER_DEG_LON * math.cos(lat)), cell_size_m / M_PER_DEG_LAT)
    else:
        size = (cell_size_m / factor, cell_size_m / factor)
        # Snap to multiples of the cell size so reprojected maps of one field share a lattice.
        west = math.floor(west / size[0]) * size[0]
        north = math.ceil(north / size[1]) * size[1]
    out = grid_from_bounds((west, south, east, north), size, dst_crs, source=grid.source,
                           format=grid.format, product=grid.product, quantity=grid.quantity, unit=grid.unit,
                           map_unit=grid.map_unit, density_kg_l=grid.density_kg_l,
                           seed_mass_g=grid.seed_mass_g, zone_rates_kg_ha=grid.zone_rates_kg_ha)
    rasterio.warp.reproject(grid.rates_kg_ha, out.rates_kg_ha, src_transform=grid.transform,
                            src_crs=CRS.from_wkt(grid.crs.to_wkt()), src_nodata=np.nan,
                            dst_transform=out.transform, dst_crs=CRS.from_wkt(dst_crs.to_wkt()),
                            dst_nodata=np.nan, resampling=_resampling_for(grid, cell_size_m),
                            num_threads=WARP_THREADS)
    return out


# GDAL's warper puts a target cell centre within ~0.02 cell of where pyproj puts it: on a 2000 x 2000
# zone map 1 cell in 15,000, whose centre lies that close to a zone edge, takes the neighbouring zone.
WARP_THREADS = 2
ZONE_LEVELS = 64  # a map with at most this many distinct rates is a zone map


def _resampling_for(grid: Grid, cell_size_m: float):
    """How to resample `grid` onto cells of `cell_size_m`.

    * A zone map (at most `ZONE_LEVELS` distinct rates): nearest neighbour, so every cell keeps one
      of the zones' rates and zone edges stay sharp.
    * A continuous map onto coarser cells: the area-weighted average of the rates a cell covers
      (what it receives on average; the product over the map is kept).
    * A continuous map onto cells as fine or finer: bilinear between cell centres (no staircase of
      half a cell at every row and column).
    """
    if _is_zone_map(grid.rates_kg_ha):
        return Resampling.nearest
    if cell_size_m > min(_cell_size_metres(grid)) * (1.0 + 1e-6):
        return Resampling.average
    return Resampling.bilinear


def _is_zone_map(rates: np.ndarray) -> bool:
    flat = rates.ravel()
    sample = flat[:: max(1, flat.size // 65_536)]  # a strided sample rules most continuous maps out fast
    levels = np.unique(sample[~np.isnan(sample)])
    if levels.size > ZONE_LEVELS:
        return False
    if levels.size == 0:
        return True
    at = np.minimum(np.searchsorted(levels, flat), levels.size - 1)
    return bool(np.all((levels[at] == flat) | np.isnan(flat)))


def field_overlap(grid: Grid, polygon_or_bounds, crs: pyproj.CRS) -> float:
    """See `Grid.check_overlap`."""
    if isinstance(polygon_or_bounds, shapely.Geometry):
        field = polygon_or_bounds
    else:
        try:
            minx, miny, maxx, maxy = (float(v) for v in polygon_or_bounds)
        except (TypeError, ValueError):
            raise MapError(f"check_overlap: {polygon_or_bounds!r} is neither a shapely geometry nor "
                           "(minx, miny, maxx, maxy) bounds") from None
        field = shapely.box(minx, miny, maxx, maxy)
    if field.is_empty or field.area <= 0.0:
        raise MapError("check_overlap: the field has no area")
    if crs != grid.crs:
        # Densify so long straight edges follow the projection's curvature.
        span = max(field.bounds[2] - field.bounds[0], field.bounds[3] - field.bounds[1])
        field = shapely.segmentize(field, span / 50.0)
        field = shapely.transform(field, lambda x, y: transform_xy(x, y, crs, grid.crs), interleaved=False)
    if not field.is_valid:
        field = shapely.make_valid(field)
    area = field.area
    if not math.isfinite(area) or area <= 0.0:
        raise MapError(f"check_overlap: the field cannot be expressed in the map's CRS {crs_label(grid.crs)}")
    share = shapely.box(*grid.bounds).intersection(field).area / area
    if share <= 0.0:
        to_wgs84 = lambda x, y: transform_xy(x, y, grid.crs, WGS84)  # noqa: E731
        fb = shapely.transform(field, to_wgs84, interleaved=False).bounds
        raise MapError(f"{grid.source or 'map'}: the map (WGS84 bounds {_fmt(grid.bounds_wgs84)}) and the "
                       f"field (WGS84 bounds {_fmt(fb)}) do not overlap")
    return float(share)


def _fmt(b) -> str:
    return "[" + ", ".join(f"{v:.6f}" for v in b) + "]"
