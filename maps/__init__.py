"""vrsim maps: prescription grids from the formats farm software writes, CRS-correct lookup,
synthetic maps, rate policies off the map, the deposition engine (as-applied rasters through a
machine's footprint: `AsApplied`, `ColumnDeposit`, the footprint kinds of `maps.footprint` and a
spinner's `SpinnerThrow`), and as-applied logs (ISO 11783 TimeLogs in TASKDATA, point shapefiles and
GeoPackages) in and out.

>>> from maps import Grid, read_map, write_map, synthetic, AsApplied, Strips, RatePolicy
>>> from maps import PointLog, read_point_log, write_points, write_taskdata, read_timelogs
"""

import importlib

from maps import synthetic
from maps.as_applied import AsApplied
from maps.columns import AppliedColumns, ColumnDeposit
from maps.crs import utm_crs_for
from maps.footprint import FOOTPRINTS, Footprint, Samples, Strips, footprint_kind, register_footprint
from maps.grid import DEFAULT_MAX_CELLS, Grid, LookupResult, grid_from_bounds
from maps.io import read_map, write_map
from maps.policy import RatePolicy
from maps.spread_footprint import SpinnerThrow
from maps.warn import MapWarning

# The as-applied log modules load on first use (module __getattr__): `import maps` stays as fast.
_LAZY = {
    "PointLog": "maps.pointlog",
    "read_point_log": "maps.pointlog",
    "write_points": "maps.pointlog_write",
    "TimeLog": "maps.timelog",
    "read_timelogs": "maps.timelog",
    "write_taskdata": "maps.taskdata",
    "read_taskdata_log": "maps.taskdata",
}

__all__ = [
    "Grid",
    "LookupResult",
    "read_map",
    "write_map",
    "synthetic",
    "AsApplied",
    "AppliedColumns",
    "ColumnDeposit",
    "Footprint",
    "Samples",
    "Strips",
    "SpinnerThrow",
    "FOOTPRINTS",
    "footprint_kind",
    "register_footprint",
    "RatePolicy",
    "utm_crs_for",
    "grid_from_bounds",
    "MapWarning",
    "DEFAULT_MAX_CELLS",
    *_LAZY,
]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'maps' has no attribute {name!r}")
