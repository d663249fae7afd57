"""Application-rate units: what vrsim converts between, and how.

Mass per area (kg/ha, t/ha, lb/ac) and volume per area (L/ha, gal/ac (US), fl oz/ac); a mass rate
and a volume rate do not convert without the product's density, which vrsim does not guess.
"""

from __future__ import annotations

import numpy as np

from common import MapError

# unit -> (kind, factor to kg/ha or L/ha)
_HA_PER_AC = 0.40468564224
RATE_UNITS = {
    "kg/ha": ("mass", 1.0),
    "t/ha": ("mass", 1000.0),
    "lb/ac": ("mass", 0.45359237 / _HA_PER_AC),
    "L/ha": ("volume", 1.0),
    "gal/ac": ("volume", 3.785411784 / _HA_PER_AC),
    "floz/ac": ("volume", 0.0295735295625 / _HA_PER_AC),
}


def convert_rate(values, unit: str, to_unit: str) -> np.ndarray:
    """Rates in `unit` expressed in `to_unit` (both in `RATE_UNITS`, of the same kind)."""
    known = sorted(RATE_UNITS)
    if unit not in RATE_UNITS or to_unit not in RATE_UNITS:
        bad = unit if unit not in RATE_UNITS else to_unit
        raise MapError(f"rate unit {bad!r} is not one vrsim converts; known: {known}")
    (kind, f_from), (kind_to, f_to) = RATE_UNITS[unit], RATE_UNITS[to_unit]
    if kind != kind_to:
        raise MapError(f"cannot convert a {kind} rate ({unit}) to a {kind_to} rate ({to_unit}) without the "
                       "product's density")
    return np.asarray(values, dtype=np.float64) * (f_from / f_to)


def base_unit(unit: str) -> str:
    """kg/ha for a mass rate, L/ha for a volume rate (`unit` in `RATE_UNITS`)."""
    return "kg/ha" if RATE_UNITS[unit][0] == "mass" else "L/ha"
