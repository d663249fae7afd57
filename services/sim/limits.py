"""Machine limits: can the meter apply the map at the working speeds, before anything moves?

The metering shaft must turn at ``rate * speed * width / 10 000 / kg_per_rev * 60`` rpm
(`vehicle.Implement.target_shaft_rpm`) and can only turn within ``[shaft_rpm_min, shaft_rpm_max]``
while applying. So the map's highest rate over the full width at the highest working speed must need
no more than ``shaft_rpm_max``, and its lowest positive rate at the lowest working speed no less than
``shaft_rpm_min``. Where it does not, the run clips the target and applies less (or more) than the
map asks; `services.sim.metrics.limit_metrics` measures how much of the run that was (each drive's
target: with a drive per section, one section's drive on a bound flags the tick).

Speeds are the working speed with its slow variation (``[tractor] speed_variation_pct`` either way)
and the headland speed if one is set; turns, starts and stops are not working speeds. With sections
off the width is narrower and the shaft slower: `min_width_m` says below which width on the lowest
rate needs less than ``shaft_rpm_min`` at the lowest speed.

What to change when it cannot: the working speeds (`MachineCheck.min_speed_m_s` to `max_speed_m_s`), or
the meter constant (another roller or gear: the shaft speed is inversely proportional to ``kg_per_rev``,
so ``kg_per_rev_min`` to ``kg_per_rev_max`` puts the needed speeds inside the shaft's range at the
working speeds as they are). The terminal's configured constant is what it computes with, so the check
uses it, not the product's true one (`vehicle.product`).

The rates are the map's as the machine meets them (`_map_rates`): a raster's cell values inside the
field, or a vector map's zone rates. Rasterizing zone polygons gives a cell on a zone edge the
area-weighted mean of the zones it covers (`maps.zones`): a 0 and a 10 lb/ac zone make edge cells of
1.11 lb/ac, which no zone asks for and which, taken for the map's lowest rate, would ask the meter to
turn nine times slower. So a vector map's lowest positive and highest rate are those of the zones whose
rates the field's cells hold; the check says which rule it used (`MachineCheck.rates_from`).

Advice names only what would change something, and only field speeds (up to
`vehicle.driver.MAX_WORKING_SPEED_M_S`): the speeds within it at which the machine can
(`MachineCheck.speed_window_m_s`), the meter constants that can at the working speeds as they are.

Each machine kind checks its own actuator (`services.sim.machines.Machine.machine_check`): by default
the shaft (`shaft_check`); a kind with another one gives its own `MachineCheck` (a sprayer checks its
nozzles, `services.sim.machines.sprayer._SprayerCheck`). Both live below the machine kinds, which
return them (`services.sim.machines.check`); this module reads the map's rates and asks the kind.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.machines.check import (
    RATES_FROM_CELLS,
    RATES_FROM_ZONES,
    MachineCheck,
    check_units,
    rate_text,
    shaft_check,
)
from vrsim.vehicle import DriveConfig, Implement

__all__ = ["RATES_FROM_CELLS", "RATES_FROM_ZONES", "ZONE_RATE_RTOL", "MachineCheck", "check_units",
           "machine_check", "rate_text", "shaft_check", "working_speeds"]

# A cell inside one zone holds the zone's rate to rounding: the mean of its sub-cells (64 equal values
# summed), a unit conversion, a reprojection's interpolation between equal neighbours.
ZONE_RATE_RTOL = 1e-9


def working_speeds(drive: DriveConfig) -> tuple[float, float]:
    """Lowest and highest working speed, m/s: the working speed with its variation, and the headland
    speed if one is set."""
    share = drive.speed_variation_pct / 100.0
    speeds = [drive.working_speed_m_s * (1.0 - share), drive.working_speed_m_s * (1.0 + share)]
    if drive.headland_speed_m_s is not None:
        speeds.append(drive.headland_speed_m_s)
    return min(speeds), max(speeds)


def _map_rates(rates_kg_ha, zone_rates_kg_ha=None) -> tuple[np.ndarray, str]:
    """The map's rates as the machine meets them, and which rule gave them (`MachineCheck.rates_from`).

    Parameters
    ----------
    rates_kg_ha : array_like
        The map's cells inside the field (NaN: none).
    zone_rates_kg_ha : array_like, optional
        A vector map's zone rates (`maps.Grid.zone_rates_kg_ha`); None: a raster.

    Returns
    -------
    rates : ndarray
        A raster's: its cells' values (`RATES_FROM_CELLS`). A vector map's: the zone rates some cell
        holds to `ZONE_RATE_RTOL`, a cell on a zone edge holding a mean of zones that none asks for
        (`RATES_FROM_ZONES`); its cells' values should no cell hold a positive zone rate (a field no
        wider than the edge cells).
    """
    rates = np.asarray(rates_kg_ha, float).ravel()
    rates = rates[np.isfinite(rates)]
    zones = np.unique(np.asarray([] if zone_rates_kg_ha is None else zone_rates_kg_ha, float))
    if zones.size == 0 or rates.size == 0:
        return rates, RATES_FROM_CELLS
    # Each cell's nearest zone rate: the next one up or the one below it (zones sorted).
    above = np.minimum(np.searchsorted(zones, rates), zones.size - 1)
    below = np.maximum(above - 1, 0)
    nearest = np.where(np.abs(rates - zones[below]) < np.abs(zones[above] - rates), below, above)
    held = np.isclose(rates, zones[nearest], rtol=ZONE_RATE_RTOL, atol=0.0)
    met = zones[np.unique(nearest[held])]
    if not (met > 0).any() and (rates > 0).any():
        return rates, RATES_FROM_CELLS
    return met, RATES_FROM_ZONES


def machine_check(rates_kg_ha, speed_range_m_s: tuple[float, float], implement: Implement,
                  density_kg_l: float | None = 1.0, working_speed_m_s: float | None = None,
                  zone_rates_kg_ha=None) -> MachineCheck:
    """Whether `implement` can apply `rates_kg_ha` at speeds within `speed_range_m_s`: its kind's check
    (`services.sim.machines.Machine.machine_check`; a shaft's by default, `shaft_check`).

    Parameters
    ----------
    rates_kg_ha : array_like
        The map's rates inside the field (NaN and zero are left out: nothing to meter there), read as
        `_map_rates` reads them.
    speed_range_m_s : (float, float)
        Lowest and highest working speed (`working_speeds`).
    implement : vehicle.Implement
    density_kg_l : float or None
        The product's (a sprayer's map in kg/ha is L/ha times it; None: not given, which a sprayer refuses).
    working_speed_m_s : float, optional
        Where a kind that suggests a change (a sprayer's nozzle size) suggests it; default the middle of
        `speed_range_m_s`.
    zone_rates_kg_ha : array_like, optional
        A vector map's zone rates (`maps.Grid.zone_rates_kg_ha`; `_map_rates`); None: a raster.

    Raises
    ------
    VehicleError
        A machine that cannot apply the map's rates at any speed (a sprayer's nozzles), or without a
        density it needs; the message starts with the table it names.
    """
    rates, rates_from = _map_rates(rates_kg_ha, zone_rates_kg_ha)
    rates = rates[rates > 0]
    lo_rate, hi_rate = (float(rates.min()), float(rates.max())) if rates.size else (math.nan, math.nan)
    working = sum(speed_range_m_s) / 2.0 if working_speed_m_s is None else working_speed_m_s
    check = machine_for(implement).machine_check(lo_rate, hi_rate, speed_range_m_s, density_kg_l, working)
    return dataclasses.replace(check, rates_from=rates_from)


