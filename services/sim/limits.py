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
the shaft (`shaft_check`, above); a kind with another one gives its own `MachineCheck` (a sprayer
checks its nozzles, `services.sim.machines.sprayer._SprayerCheck`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from maps.units import in_units, shown_range, shown_text, unit_system
from services.sim.metrics import RATE_UNIT, rate_key
from vehicle import DriveConfig, Implement
from vehicle.driver import MAX_WORKING_SPEED_M_S

RATES_FROM_CELLS = "cell values"
RATES_FROM_ZONES = "zone rates of the vector map"
# A cell inside one zone holds the zone's rate to rounding: the mean of its sub-cells (64 equal values
# summed), a unit conversion, a reprojection's interpolation between equal neighbours.
ZONE_RATE_RTOL = 1e-9


@dataclass(frozen=True)
class MachineCheck:
    """Whether the machine can apply a map, and at which working speeds.

    Attributes
    ----------
    rate_min_kg_ha, rate_max_kg_ha : float
        Lowest positive and highest rate the map asks for inside the field (NaN: none positive).
    speed_min_m_s, speed_max_m_s : float
        Lowest and highest working speed.
    rpm_min, rpm_max : float
        Shaft speed the lowest rate needs at the lowest speed and the highest rate at the highest
        speed, over the full width.
    shaft_rpm_min, shaft_rpm_max : float
        The shaft's range.
    min_speed_m_s, max_speed_m_s : float
        Lowest and highest working speed at which the full width applies the whole map.
    min_width_m : float
        Narrowest width on with which the lowest rate at the lowest speed still needs at least
        ``shaft_rpm_min`` (sections switched off narrow it).
    narrowest_section_m : float
        The implement's narrowest section.
    kg_per_rev : float
        The configured meter constant, kg/rev.
    kg_per_rev_min, kg_per_rev_max : float
        The meter constants with which the full width applies the whole map at every working speed,
        kg/rev (``kg_per_rev_max`` infinite for a shaft whose range starts at 0 rpm; NaN for a map
        with no positive rate). ``kg_per_rev_min > kg_per_rev_max``: no constant can, the map's rates
        and the working speeds span more than the shaft's range.
    rates_from : str
        Which of the map's values the rates are (`_map_rates`): `RATES_FROM_CELLS`, a raster's cells
        inside the field, or `RATES_FROM_ZONES`, the zone rates the field's cells hold.
    """

    rate_min_kg_ha: float
    rate_max_kg_ha: float
    speed_min_m_s: float
    speed_max_m_s: float
    rpm_min: float
    rpm_max: float
    shaft_rpm_min: float
    shaft_rpm_max: float
    min_speed_m_s: float
    max_speed_m_s: float
    min_width_m: float
    narrowest_section_m: float
    kg_per_rev: float
    kg_per_rev_min: float
    kg_per_rev_max: float
    rates_from: str = RATES_FROM_CELLS
    # The unit of ``rpm_*`` and ``shaft_rpm_*``: the shaft's speed, or what a kind checks instead.
    RPM_UNIT: ClassVar[str] = "rpm"

    @property
    def can_apply(self) -> bool:
        """The full width applies the whole map at every working speed (vacuously true for a map with
        no positive rate)."""
        if not math.isfinite(self.rate_max_kg_ha):
            return True
        return self.shaft_rpm_min <= self.rpm_min and self.rpm_max <= self.shaft_rpm_max

    def in_rate_unit(self, grid=None) -> dict:
        """The check's rates (its ``*_kg_ha`` figures) in the map's own unit, keyed as
        `services.sim.metrics.in_rate_unit` keys a run's: ``{"rate_min": ..., "rate_max": ...}``.

        Parameters
        ----------
        grid : maps.Grid, optional
            The map (`maps.Grid.in_map_unit` converts); None: kg/ha.
        """
        convert = (lambda v: v) if grid is None else grid.in_map_unit
        return {rate_key(k): float(convert(v)) for k, v in vars(self).items() if k.endswith("_kg_ha")}

    def text(self, grid=None, units: str | None = None) -> str:
        """Three or four lines for the run's printout (the verdict, which rates, the speeds at which it
        can, ...); two more naming what to change if it cannot. Rates in the unit of `grid`
        (`in_rate_unit`; None: kg/ha), every figure as shown in `units` ("metric" or "us",
        `maps.units.in_units`; None: as the run shows them, in the system of the map's unit)."""
        if not math.isfinite(self.rate_max_kg_ha):
            return "Machine check: the map asks for no product inside the field."
        units = check_units(grid, units)
        verdict = "can apply the map" if self.can_apply else "CANNOT apply the whole map"
        lines = [f"Machine check: the meter {verdict}: {self.rates_text(grid, units)} at "
                 f"{shown_range(self.speed_min_m_s, self.speed_max_m_s, 'm/s', units)} needs "
                 f"{self.rpm_min:.1f}-{self.rpm_max:.1f} rpm of a {self.shaft_rpm_min:g}-"
                 f"{self.shaft_rpm_max:g} rpm shaft.",
                 self.rates_line(), self.speeds_line(units)]
        if self.rpm_max > self.shaft_rpm_max:
            lines.append(f"  Above {shown_text(self.max_speed_m_s, 'm/s', units)} the highest rates are "
                         "under-applied.")
        if self.rpm_min < self.shaft_rpm_min:
            lines.append("  At every field speed the lowest rates are over-applied."
                         if self.min_speed_m_s > MAX_WORKING_SPEED_M_S else
                         f"  Below {shown_text(self.min_speed_m_s, 'm/s', units)} the lowest rates are "
                         "over-applied.")
        elif self.min_width_m > self.narrowest_section_m:
            width = shown_text(self.min_width_m, "m", units, ".1f")
            lines.append(f"  With less than {width} of sections on, the lowest rate at the lowest speed is "
                         "over-applied.")
        if not self.can_apply:
            lines += self._remedies(units)
        return "\n".join(lines)

    def rates_text(self, grid=None, units: str = "metric") -> str:
        """``"100-150 lb/ac"``: the map's lowest positive and highest rate in the unit of `grid` (None:
        kg/ha), or its counterpart in `units` (gal/ac in "metric" as L/ha)."""
        rates, unit = self.in_rate_unit(grid), RATE_UNIT if grid is None else grid.map_unit
        (lo, shown), (hi, _) = (in_units(rates[k], unit, units) for k in ("rate_min", "rate_max"))
        return f"{rate_text(lo)}-{rate_text(hi)} {shown}"

    def rates_line(self) -> str:
        """Which of the map's values the check read (`rates_from`), one line."""
        if self.rates_from == RATES_FROM_ZONES:
            return ("  Rates: the zone rates of the vector map inside the field (a cell on a zone edge, "
                    "rasterized to a mean of two zones, is no rate of its own).")
        return f"  Rates: the map's {self.rates_from} inside the field."

    @property
    def speed_window_m_s(self) -> tuple[float, float] | None:
        """The working speeds at which the full width applies the whole map, m/s, up to the highest
        field speed (`vehicle.driver.MAX_WORKING_SPEED_M_S`); None: no field speed."""
        lo, hi = self.min_speed_m_s, min(self.max_speed_m_s, MAX_WORKING_SPEED_M_S)
        return (lo, hi) if lo <= hi else None

    def speeds_line(self, units: str = "metric") -> str:
        """The working speeds at which it can (`speed_window_m_s`), one line, in `units`."""
        window = self.speed_window_m_s
        if window is None:
            return f"  Working speeds at which it can: none ({self._no_speed(units)})."
        lo, hi = window
        notes = [f"highest {hi * 3.6:.1f} km/h"] if units == "metric" else []  # as a tractor shows it
        if hi < self.max_speed_m_s:
            notes.append(f"field speeds end at {shown_text(MAX_WORKING_SPEED_M_S, 'm/s', units, '.3g')}")
        notes_text = f" ({'; '.join(notes)})" if notes else ""
        return (f"  Working speeds at which it can: {shown_range(lo, hi, 'm/s', units, between=' to ')}"
                f"{notes_text}.")

    def _no_speed(self, units: str = "metric") -> str:
        """Why no field speed applies the whole map."""
        if self.min_speed_m_s <= self.max_speed_m_s:
            return (f"it needs {shown_text(self.min_speed_m_s, 'm/s', units)} or more, beyond field speeds, "
                    f"which end at {shown_text(MAX_WORKING_SPEED_M_S, 'm/s', units, '.3g')}")
        return f"the map's rates span {self.rate_span:.1f}x, the shaft's speeds {self.shaft_span:.1f}x"

    def speed_remedy(self, units: str = "metric") -> str:
        """The first line of what to change: the working speeds within `speed_window_m_s`, else why none."""
        window = self.speed_window_m_s
        if window is not None:
            return (f"  To apply it all: keep the working speeds within "
                    f"{shown_range(*window, 'm/s', units)}, or")
        if self.min_speed_m_s <= self.max_speed_m_s:
            return f"  No field speed applies it all: {self._no_speed(units)}; instead"
        return f"  No working speed applies it all: {self._no_speed(units)}; narrow the map's range, or"

    def _remedies(self, units: str = "metric") -> list[str]:
        """What to change so that the full width applies the whole map: the speeds, or the meter."""
        speeds = shown_range(self.speed_min_m_s, self.speed_max_m_s, "m/s", units)
        lines = [self.speed_remedy(units)]
        if self.kg_per_rev_min <= self.kg_per_rev_max:
            lo = f"{self.kg_per_rev_min:.4g}"
            constants = (f"{lo}-{self.kg_per_rev_max:.4g} kg/rev" if math.isfinite(self.kg_per_rev_max)
                         else f"{lo} kg/rev or more")
            lines.append(f"  set [implement] kg_per_rev to {constants} (now "
                         f"{self.kg_per_rev:g}: another roller or gear) to apply it at {speeds}.")
        else:
            lines.append(f"  no meter constant applies it at {speeds}: the map's rates and these speeds "
                         f"span {self.rate_span * self.speed_max_m_s / self.speed_min_m_s:.1f}x, the "
                         f"shaft's speeds {self.shaft_span:.1f}x; narrow the working speeds.")
        return lines

    @property
    def rate_span(self) -> float:
        """Highest over lowest positive rate of the map."""
        return self.rate_max_kg_ha / self.rate_min_kg_ha

    @property
    def shaft_span(self) -> float:
        """Highest over lowest shaft speed (infinite for a range from 0 rpm)."""
        return self.shaft_rpm_max / self.shaft_rpm_min if self.shaft_rpm_min > 0 else math.inf


def check_units(grid, units: str | None) -> str:
    """`units`, or the system of `grid`'s rate unit when None (`maps.units.unit_system`; no grid:
    metric)."""
    return unit_system(None if grid is None else grid.map_unit, units)


def rate_text(value: float) -> str:
    """A rate for the check's line: whole numbers as before (kg/ha, lb/ac), three figures below 10
    (t/ha, g/m2)."""
    return f"{value:.0f}" if abs(value) >= 10 else f"{value:.3g}"


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
    # Imported here: the machines' base imports this module (`shaft_check`, `MachineCheck`).
    from services.sim.machines import machine_for

    rates, rates_from = _map_rates(rates_kg_ha, zone_rates_kg_ha)
    rates = rates[rates > 0]
    lo_rate, hi_rate = (float(rates.min()), float(rates.max())) if rates.size else (math.nan, math.nan)
    working = sum(speed_range_m_s) / 2.0 if working_speed_m_s is None else working_speed_m_s
    check = machine_for(implement).machine_check(lo_rate, hi_rate, speed_range_m_s, density_kg_l, working)
    return dataclasses.replace(check, rates_from=rates_from)


def shaft_check(implement: Implement, lo_rate: float, hi_rate: float,
                speed_range_m_s: tuple[float, float]) -> MachineCheck:
    """`machine_check` of a metering shaft: the lowest positive and highest rate inside the field,
    kg/ha (NaN: none positive), at speeds within `speed_range_m_s`."""
    v_lo, v_hi = speed_range_m_s
    width = implement.width_m
    rpm_min = float(implement.target_shaft_rpm(lo_rate, v_lo, width))
    rpm_max = float(implement.target_shaft_rpm(hi_rate, v_hi, width))
    # rpm is proportional to rate x speed x width: the speed (width) where the bound is reached.
    per_m_s = float(implement.target_shaft_rpm(hi_rate, 1.0, width))
    per_m_s_lo = float(implement.target_shaft_rpm(lo_rate, 1.0, width))
    per_m = float(implement.target_shaft_rpm(lo_rate, v_lo, 1.0))
    # ... and the shaft speed is inversely proportional to the meter constant.
    kg = implement.kg_per_rev
    kg_max = kg * rpm_min / implement.shaft_rpm_min if implement.shaft_rpm_min > 0 else math.inf
    return MachineCheck(
        rate_min_kg_ha=lo_rate, rate_max_kg_ha=hi_rate, speed_min_m_s=v_lo, speed_max_m_s=v_hi,
        rpm_min=rpm_min, rpm_max=rpm_max,
        shaft_rpm_min=implement.shaft_rpm_min, shaft_rpm_max=implement.shaft_rpm_max,
        min_speed_m_s=implement.shaft_rpm_min / per_m_s_lo if per_m_s_lo > 0 else math.nan,
        max_speed_m_s=implement.shaft_rpm_max / per_m_s if per_m_s > 0 else math.nan,
        min_width_m=implement.shaft_rpm_min / per_m if per_m > 0 else math.nan,
        narrowest_section_m=float(implement.section_widths.min()),
        kg_per_rev=kg, kg_per_rev_min=kg * rpm_max / implement.shaft_rpm_max,
        kg_per_rev_max=kg_max if math.isfinite(hi_rate) else math.nan,
    )
