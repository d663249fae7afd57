"""What a machine check finds (`MachineCheck`) and the default check, a metering shaft's (`shaft_check`).

Below the machine kinds: each kind's `services.sim.machines.Machine.machine_check` gives a
`MachineCheck` (by default the shaft's, `shaft_check`; a sprayer's checks its nozzles,
`services.sim.machines.sprayer._SprayerCheck`), and `services.sim.limits.machine_check` reads the map's
rates and asks the implement's kind. `services.sim.limits` explains the check and re-exports these names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from vrsim.maps.units import in_units, shown_range, shown_text, unit_system
from vrsim.services.sim.rate_units import RATE_UNIT, rate_key
from vrsim.vehicle import Implement
from vrsim.vehicle.driver import MAX_WORKING_SPEED_M_S

RATES_FROM_CELLS = "cell values"
RATES_FROM_ZONES = "zone rates of the vector map"

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
