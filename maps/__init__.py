"""vrsim maps: prescription grids from the formats farm software writes, CRS-correct lookup,
synthetic maps, rate policies off the map, the deposition engine (as-applied rasters through a
machine's footprint: `AsApplied`, `ColumnDeposit`, the footprint kinds of `maps.footprint` and a
spinner's `SpinnerThrow`), and as-applied logs (ISO 11783 TimeLogs in TASKDATA, point shapefiles and
GeoPackages) in and out.

>>> from vrsim.maps import Grid, read_map, write_map, synthetic, AsApplied, Strips, RatePolicy
>>> from vrsim.maps import PointLog, read_point_log, write_points, write_taskdata, read_timelogs
"""

import importlib

from vrsim.maps import synthetic
from vrsim.maps.as_applied import AsApplied
from vrsim.maps.columns import AppliedColumns, ColumnDeposit
from vrsim.maps.crs import utm_crs_for
from vrsim.maps.footprint import FOOTPRINTS, Footprint, Samples, Strips, footprint_kind, register_footprint
from vrsim.maps.grid import DEFAULT_MAX_CELLS, Grid, LookupResult, grid_from_bounds
from vrsim.maps.io import read_map, write_map
from vrsim.maps.policy import RatePolicy
from vrsim.maps.spread_footprint import SpinnerThrow
from vrsim.maps.warn import MapWarning

# The as-applied log modules load on first use (module __getattr__): `import maps` stays as fast.
_LAZY = {
    "PointLog": "vrsim.maps.pointlog",
    "read_point_log": "vrsim.maps.pointlog",
    "write_points": "vrsim.maps.pointlog_write",
    "TimeLog": "vrsim.maps.timelog",
    "read_timelogs": "vrsim.maps.timelog",
    "write_taskdata": "vrsim.maps.taskdata",
    "read_taskdata_log": "vrsim.maps.taskdata",
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
