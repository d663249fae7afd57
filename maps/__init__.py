"""vrsim maps: prescription grids from the formats farm software writes, CRS-correct lookup,
synthetic maps, rate policies off the map, and as-applied accumulation.

>>> from maps import Grid, read_map, write_map, synthetic, AsApplied, RatePolicy
"""

from maps import synthetic
from maps.as_applied import AsApplied
from maps.crs import utm_crs_for
from maps.grid import DEFAULT_MAX_CELLS, Grid, LookupResult, grid_from_bounds
from maps.io import read_map, write_map
from maps.policy import RatePolicy
from maps.warn import MapWarning

__all__ = [
    "Grid",
    "LookupResult",
    "read_map",
    "write_map",
    "synthetic",
    "AsApplied",
    "RatePolicy",
    "utm_crs_for",
    "grid_from_bounds",
    "MapWarning",
    "DEFAULT_MAX_CELLS",
]
