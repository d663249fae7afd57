"""``sprayer``: a boom of nozzles fed through a regulating valve and a flow meter (`vehicle.sprayer`).

The loop closes the boom's *metered* flow: a drive's "shaft speed" is metered L/min and its
"revolutions" metered litres (`controller.linearize_flow`: the flow plant's tangent at the map's
working point as a `PlantParams`, so every controller kind runs it through `controller.build_loop`).
The terminal sets its target from the flow meter's configured constant, so the loop holds the
*reading* on target; the true flow is the reading over the meter's gain (``flow_meter_error_pct``),
and product is true litres times ``[product] density_kg_l`` (`Sprayer.kg_per_rev`, the one place in
`services.sim.core.ControlCore._metered_kg`). The map's kg/ha are litres per hectare times the density.
The density also sets what a nozzle passes at a pressure (`vehicle.sprayer.density_flow_factor`: its
water rating times ``sqrt(1 / SG)``): the boom's orifice coefficient, the pressure range's flows, PWM's
open flow, the machine check and its nozzle advice all take it from the product.

- ``control = "flow"``: one loop for the boom. Its target is the flow for the rate at the boom's
  centre where spray now lands, at the centre's sensed speed, over the open sections' nozzles, held
  within the nozzles' pressure range (their flows at ``pressure_range_bar``: the machine's limit);
  every open nozzle sprays alike, so each open section's strip gets its share by width.
- ``control = "pwm"``: the pump holds ``pwm_pressure_bar`` and each nozzle's duty sets its flow: a
  nozzle's target flow is its section's rate at its own ground speed ``v - yaw_rate * offset``
  (per-nozzle turn compensation, `vehicle.sprayer.pwm_duty_pct`), its duty within ``duty_range_pct``.
  A loop per section closes its nozzles' flow (a drive per section, landing at the section's own
  point as `section_drives`'); with one linear plant for all, the sections' loops add up to the
  boom's loop on the one meter (superposition), the duty trim being the actuator (it acts within a
  pulse period: the plant's time constant is ``1 / pwm_hz``). Each section's strip carries its own
  loop's product. The pulse trains' ripple within a tick (`pwm_open_fraction`) averages out over a
  strip's ticks and is not drawn.

Each section's nozzles are those whose centres lie across it (a section is a whole number of nozzle
spacings wide); a closed section's valve shuts them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from vrsim.common import ScenarioError, VehicleError, VrsimError
from vrsim.controller import FlowLinearization, FlowPlant, PlantParams, linearize_flow
from vrsim.maps.units import in_units, shown_range
from vrsim.services.sim.machines.base import Machine
from vrsim.services.sim.machines.check import MachineCheck, check_units, rate_text
from vrsim.services.sim.machines.registry import register_machine
from vrsim.services.sim.section_landing import StripPlan
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle import Implement
from vrsim.vehicle.sprayer import (
    REF_PRESSURE_BAR,
    WATER_DENSITY_KG_L,
    SprayerSpec,
    boom_flow_l_min,
    density_flow_factor,
    nozzle_flow_l_min,
    pwm_duty_pct,
)

_WORKING_POINT_MARGIN = 0.02   # keep the linearization's flow this far inside the valve's range


@register_machine
class Sprayer(Machine):
    """A boom sprayer (see the module's docstring)."""

    kind = "sprayer"
    keys = SprayerSpec
    product_form = "liquid"   # its calibration: the flow meter's catch test

    def __init__(self, implement: Implement, field_polygon=None):
        super().__init__(implement, field_polygon)
        spec = self.spec = implement.machine
        self.layout_error = None   # a boom the nozzles do not fit: `loop_plant` names it with the file
        try:
            self.nozzle_offsets_m = -spec.nozzle_offsets_m(implement.width_m)   # left positive, (N,)
        except VrsimError as exc:
            self.layout_error, self.nozzle_offsets_m = str(exc), np.zeros(1)
        edges = implement.width_m / 2 - np.concatenate([[0.0], np.cumsum(implement.section_widths)])
        # Section of each nozzle: the one its centre lies across (sections left to right).
        self.nozzle_section = np.clip(np.searchsorted(-edges, -self.nozzle_offsets_m) - 1, 0,
                                      implement.sections - 1)
        self.nozzles_per_section = np.bincount(self.nozzle_section, minlength=implement.sections)
        # A section is a whole number of nozzles (its valve shuts them), so its strip gets what they spray.
        off = np.abs(implement.section_widths - self.nozzles_per_section * spec.nozzle_spacing_m)
        if self.layout_error is None and (off > 0.01 * spec.nozzle_spacing_m).any():
            bad = int(np.argmax(off))
            self.layout_error = (f"section_widths_m: section {bad + 1} ({implement.section_widths[bad]:g} m) "
                                 f"is not a whole number of nozzle_spacing_m ({spec.nozzle_spacing_m:g} m)")
        self.pwm = spec.control == "pwm"
        self.density_kg_l = 1.0   # the product's, set by `loop_plant` (a run's core)

    # --- metering -----------------------------------------------------------------------------------
    @property
    def drives(self) -> int:
        return self.implement.sections if self.pwm else 1

    @property
    def drive_share(self) -> np.ndarray:
        return np.ones(self.drives)   # each loop meters its own litres

    @property
    def loop_quantity(self) -> tuple[str, str]:
        """The metered flow, L/min: the boom's (flow control) or a section's nozzles' (PWM)."""
        return ("section's metered flow" if self.pwm else "boom's metered flow"), "L/min"

    def loop_plant(self, plant: PlantParams, scenario, grid) -> PlantParams:
        """The flow plant's tangent at the working point (the map's median positive rate at the
        working speed, each nozzle's flow held in its range; one section's nozzles under PWM, the
        valve's time constant then a pulse period), its current range the valve's flows. Refuses a
        product that is not liquid, or the product's calibration error (a sprayer's is its flow
        meter's: `check_liquid`); binds the product's density."""
        if self.layout_error is not None:
            raise ScenarioError(f"{scenario.source}: [implement] {self.layout_error}")
        product = check_liquid(scenario)
        self.density_kg_l = product.density_kg_l
        fp, lin = self.flow_linearization(scenario, grid)
        # The tangent is the valve's local gain; the flows it reaches are the valve's own, shut to full
        # (the tangent alone would stop short of a convex curve's top: a bypass valve's 49.6 of 62.7 L/min
        # from 34 L/min), so the loop's current range is where the tangent gives those flows.
        metered_per_a = lin.slope_l_min_per_a * fp.meter_gain
        lo, hi = (flow * fp.meter_gain for flow in fp.flow_range_l_min())
        return dataclasses.replace(lin.plant, current_min_a=lo / metered_per_a,
                                   current_max_a=hi / metered_per_a, shaft_rpm_max=hi * (1.0 - 1e-9))

    def flow_linearization(self, scenario, grid) -> tuple[FlowPlant, FlowLinearization]:
        """One loop's `controller.FlowPlant` and its `controller.linearize_flow` at the working point; the
        boom's orifice coefficient is its nozzles' flow of the bound liquid (`density_kg_l`) at 3 bar."""
        spec, nozzles, density = self.spec, len(self.nozzle_offsets_m) / self.drives, self.density_kg_l
        coeff = nozzles * spec.rated_flow_l_min(density) / np.sqrt(REF_PRESSURE_BAR)
        tau = {"valve_time_constant_s": 1.0 / spec.pwm_hz} if self.pwm else {}
        fp = FlowPlant(coeff, valve=spec.valve, pressure_max_bar=spec.pressure_range_bar[1],
                       meter_gain=spec.meter.gain, **tau)
        rates = grid.rates_kg_ha[np.isfinite(grid.rates_kg_ha) & (grid.rates_kg_ha > 0)]
        rate_l_ha = float(np.median(rates)) / self.density_kg_l if rates.size else 0.0
        # The nozzles' flow there, held in their range as the targets are.
        per_nozzle = float(boom_flow_l_min(rate_l_ha, scenario.tractor.working_speed_m_s,
                                           spec.nozzle_spacing_m))
        flow = nozzles * float(np.clip(per_nozzle, *spec.nozzle_flow_range_l_min(density_kg_l=density)))
        lo, hi = fp.flow_range_l_min()
        margin = _WORKING_POINT_MARGIN * (hi - lo)
        return fp, linearize_flow(fp, float(np.clip(flow, lo + margin, hi - margin)))

    def machine_check(self, lo_rate_kg_ha: float, hi_rate_kg_ha: float, speed_range_m_s: tuple[float, float],
                      density_kg_l: float | None, working_speed_m_s: float) -> _SprayerCheck:
        """The nozzles for the shaft (`_SprayerCheck`): the boom's flow (L/min) must stay within what its
        nozzles give in their pressure range (under PWM: their duty range at the held pressure;
        `vehicle.sprayer.SprayerSpec.nozzle_flow_range_l_min`) of the liquid (its density's
        `vehicle.sprayer.density_flow_factor` times water's), the map's kg/ha being L/ha times the
        liquid's density. Sections closing do not change a nozzle's flow, so no width limit; what to
        change is the working speeds or the nozzle size (`SprayerSpec.nozzles_for`). A nozzle that
        cannot apply the map's rates at any speed, a boom its nozzles do not fit, or no density:
        `VehicleError` naming the table."""
        if self.layout_error is not None:   # `machine_check` alone builds no loop: said here too
            raise VehicleError(f"[implement] {self.layout_error}")
        if density_kg_l is None:
            raise VehicleError("[product] density_kg_l: a sprayer's kg are litres times the liquid's "
                               "density, got none (water: 1.0)")
        try:
            return self._nozzle_check(lo_rate_kg_ha, hi_rate_kg_ha, speed_range_m_s, density_kg_l,
                                      working_speed_m_s)
        except VehicleError as exc:
            raise VehicleError(f"[implement] {exc}") from None

    def _nozzle_check(self, lo_rate_kg_ha: float, hi_rate_kg_ha: float, speed_range_m_s: tuple[float, float],
                      density_kg_l: float, working_speed_m_s: float) -> _SprayerCheck:
        """`machine_check`'s figures (the nozzles' own messages unprefixed)."""
        spec, width = self.spec, self.implement.width_m
        (v_lo, v_hi), n = speed_range_m_s, spec.nozzle_count(width)
        q_lo, q_hi = spec.nozzle_flow_range_l_min(density_kg_l=density_kg_l)
        lo_l, hi_l = lo_rate_kg_ha / density_kg_l, hi_rate_kg_ha / density_kg_l
        slowest = fastest = math.nan
        suggested, advised = None, ()
        if math.isfinite(hi_rate_kg_ha):
            slowest, fastest = spec.check_rates(lo_l, hi_l, density_kg_l)
            suggested = spec.suggest_nozzle(lo_l, hi_l, working_speed_m_s, density_kg_l)
            advised = tuple(spec.nozzles_for(lo_l, hi_l, speed_range_m_s, density_kg_l))
        return _SprayerCheck(
            rate_min_kg_ha=lo_rate_kg_ha, rate_max_kg_ha=hi_rate_kg_ha,
            speed_min_m_s=v_lo, speed_max_m_s=v_hi,
            rpm_min=float(boom_flow_l_min(lo_l, v_lo, width)),
            rpm_max=float(boom_flow_l_min(hi_l, v_hi, width)),
            shaft_rpm_min=q_lo * n, shaft_rpm_max=q_hi * n, min_speed_m_s=slowest, max_speed_m_s=fastest,
            min_width_m=0.0, narrowest_section_m=float(self.implement.section_widths.min()),
            kg_per_rev=math.nan, kg_per_rev_min=math.nan, kg_per_rev_max=math.nan,
            nozzle=spec.nozzle, nozzle_flow_min_l_min=q_lo, nozzle_flow_max_l_min=q_hi,
            working_speed_m_s=working_speed_m_s, density_kg_l=density_kg_l,
            nozzle_suggested=None if suggested == spec.nozzle else suggested, nozzles_advised=advised)

    def kg_per_rev(self, product) -> float:
        """Product per metered litre, kg: the true litres behind it (the meter reads ``1 +
        flow_meter_error_pct / 100`` times what flows) times the density."""
        return product.density_kg_l / self.spec.meter.gain

    def configured_kg(self, rev, product) -> np.ndarray:
        """Litres metered times the density, kg (the meter taken at its word)."""
        return np.asarray(rev, float) * product.density_kg_l

    def landing(self, motion: Motion, lead_s: float) -> tuple[np.ndarray, ...]:
        x, y, cos, sin = motion.ahead(lead_s)
        if not self.pwm:
            return x, y, x[:, None], y[:, None]
        offset_m = self.implement.section_offsets_m
        return x, y, x[:, None] - sin[:, None] * offset_m, y[:, None] + cos[:, None] * offset_m

    def drive_open(self, states: SectionStates) -> np.ndarray:
        return states.actual if self.pwm else (states.width_on_m > 0)[:, None]

    def shut_off(self, drive_target: np.ndarray) -> np.ndarray:
        """At a zero target the boom's (PWM: the section's) shut-off valve closes, as a terminal closes
        it where the map asks for nothing: the flow valve's lowest opening never reaches the nozzles."""
        return np.asarray(drive_target) <= 0.0

    def nozzle_flow_l_min(self, rate_l_ha: np.ndarray, states: SectionStates, density_kg_l: float,
                          limits: bool = True) -> np.ndarray:
        """Each nozzle's target flow, L/min (n, N), for the rates in L/ha (n, drives) of a liquid of
        `density_kg_l`: under PWM at its section's rate and its own ground speed, its duty within the
        duty range (of the liquid's open flow); with flow control the boom's flow (for the centre's rate
        and speed over the open nozzles, within the pressure range's flows of the liquid) shared by the
        open nozzles. `limits` false lifts the ranges. 0 where the section is closed."""
        spec, open_nozzle = self.spec, states.actual[:, self.nozzle_section]
        if self.pwm:
            speed = np.abs(states.motion.ground_speed_m_s(self.nozzle_offsets_m))
            q_full = float(nozzle_flow_l_min(spec.q_ref_l_min, spec.pwm_pressure_bar, density_kg_l))
            duty = pwm_duty_pct(rate_l_ha[:, self.nozzle_section], speed, spec.nozzle_spacing_m, q_full,
                                spec.duty_range_pct if limits else (0.0, np.inf))
            return np.where(open_nozzle, duty / 100.0 * q_full, 0.0)
        per_nozzle = boom_flow_l_min(rate_l_ha[:, 0], states.motion.speed_m_s, spec.nozzle_spacing_m)
        if limits:
            q_range = spec.nozzle_flow_range_l_min(density_kg_l=density_kg_l)
            per_nozzle = np.where(per_nozzle > 0, np.clip(per_nozzle, *q_range), 0.0)
        return np.where(open_nozzle, per_nozzle[:, None], 0.0)

    def drive_targets(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        """Each loop's target, metered L/min (the terminal takes its meter at its word): the boom's
        (flow control) or each section's nozzles' (PWM)."""
        density = self.density_kg_l
        return self._per_drive(self.nozzle_flow_l_min(rate_kg_ha / density, states, density))

    def unlimited_targets(self, rate_kg_ha: np.ndarray, states: SectionStates, product) -> np.ndarray:
        """`drive_targets` with the nozzles' pressure (PWM: duty) range lifted, for `product`'s density."""
        density = product.density_kg_l
        flow = self.nozzle_flow_l_min(rate_kg_ha / density, states, density, limits=False)
        return self._per_drive(flow)

    def _per_drive(self, nozzle_flow_l_min: np.ndarray) -> np.ndarray:
        """Nozzles' flows (n, N) -> each loop's (n, drives): the boom's, or each section's nozzles'."""
        if not self.pwm:
            return nozzle_flow_l_min.sum(axis=1, keepdims=True)
        return np.add.reduceat(nozzle_flow_l_min, np.r_[0, np.cumsum(self.nozzles_per_section)[:-1]], axis=1)

    def drive_speed_m_s(self, motion: Motion) -> np.ndarray:
        """Each loop's ground speed (the controllers' context), m/s: the centre's (flow control) or each
        section's own, ``v - yaw_rate * offset`` (PWM: its nozzles' mean)."""
        if not self.pwm:
            return super().drive_speed_m_s(motion)
        return np.abs(motion.ground_speed_m_s(self.implement.section_offsets_m))

    def combined(self, per_drive: np.ndarray) -> np.ndarray:
        return per_drive.sum(axis=1)   # the boom's flow (L/min) or litres: the sections' together

    def prescribed(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        """The centre's rate (flow control); under PWM the open sections' weighted by their widths."""
        if not self.pwm:
            return rate_kg_ha[:, 0]
        widths = self.implement.section_widths
        weight = np.where(states.actual.any(axis=1, keepdims=True), states.actual, True) * widths
        return (rate_kg_ha * weight).sum(axis=1) / weight.sum(axis=1)

    def limited(self, control: dict, product=None) -> np.ndarray:
        """Where an open nozzle's target sits at an end of its flow range (the pressure range; under PWM
        the duty range at the held pressure) of `product`'s liquid (None: the one `loop_plant` bound;
        a sprayer never bound, water's)."""
        density = self.density_kg_l if product is None else product.density_kg_l
        q_lo, q_hi = self.spec.nozzle_flow_range_l_min(density_kg_l=density)
        target = np.asarray(control["drive_target_rpm"], float)
        on = np.asarray(control["sections_on"], bool)
        nozzles = (on * self.nozzles_per_section) if self.pwm else (on @ self.nozzles_per_section)[:, None]
        per_nozzle = np.divide(target, nozzles, out=np.zeros(target.shape), where=nozzles > 0)
        tol = 1e-9 * q_hi
        at_bound = (per_nozzle > 0) & ((per_nozzle <= q_lo + tol) | (per_nozzle >= q_hi - tol))
        return at_bound.any(axis=1)

    # --- deposition ---------------------------------------------------------------------------------
    def deposition(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                   cell_m: float, ticks=None, tick_m: float | None = None, first_tick: int = 0) -> StripPlan:
        return StripPlan.of(track, states, delay_s, period_s, cell_m, ticks, tick_m, first_tick,
                            own_drives=self.pwm)


@dataclass(frozen=True)
class _SprayerCheck(MachineCheck):
    """`MachineCheck` of a sprayer: ``rpm_*`` are the boom's flows (L/min) and ``shaft_rpm_*`` what its
    nozzles give over the full width; ``min_speed_m_s``/``max_speed_m_s`` where every nozzle stays in
    its range (`SprayerSpec.speed_range_m_s`); ``min_width_m`` 0 and the ``kg_per_rev`` fields NaN (no
    shaft). Adds the nozzle, its flow range and the size that would cover the map at the working speed.

    Attributes
    ----------
    nozzle : str
        The ISO 10625 size on the boom.
    nozzle_flow_min_l_min, nozzle_flow_max_l_min : float
        One nozzle's flow range of the liquid, L/min (pressure range; PWM: duty range at the held
        pressure), its water rating's times `vehicle.sprayer.density_flow_factor`.
    working_speed_m_s : float
        The tractor's working speed.
    nozzle_suggested : str or None
        The size that covers the map's rates at the working speed with the most margin (None: none, or
        the one on the boom: advice never names the setting in place).
    nozzles_advised : tuple of str
        What to change to if it cannot: the sizes other than the one on the boom that cover the map's
        rates at every working speed, the nearest smaller and larger (`SprayerSpec.nozzles_for`),
        nearer first; empty: none does.
    density_kg_l : float
        The liquid's density: the map's kg/ha over it are the L/ha the text shows; the nozzles' flows
        are of it (the text says so when it is not water's).
    """

    RPM_UNIT: ClassVar[str] = "L/min"  # ``rpm_*``, ``shaft_rpm_*``: the boom's flows
    nozzle: str = ""
    nozzle_flow_min_l_min: float = math.nan
    nozzle_flow_max_l_min: float = math.nan
    working_speed_m_s: float = math.nan
    nozzle_suggested: str | None = None
    nozzles_advised: tuple[str, ...] = ()
    density_kg_l: float = 1.0

    def text(self, grid=None, units: str | None = None) -> str:
        """The verdict, the speeds at which the nozzles stay in range and, if it cannot, what to change;
        the rates in L/ha (gal/ac in "us") and in the unit of `grid` (`in_rate_unit`; None: kg/ha) where
        that differs, every figure as shown in `units` (`maps.units.in_units`; None: in the system of
        the map's unit, as the run shows them)."""
        if not math.isfinite(self.rate_max_kg_ha):
            return "Machine check: the map asks for no product inside the field."
        units = check_units(grid, units)
        verdict = "can apply the map" if self.can_apply else "CANNOT apply the whole map"
        (lo_l, per_area), (hi_l, _) = (in_units(rate / self.density_kg_l, "L/ha", units)
                                       for rate in (self.rate_min_kg_ha, self.rate_max_kg_ha))
        rates = self.rates_text(grid, units)
        also = "" if rates.endswith(f" {per_area}") else f"({rates}) "
        liquid = ("" if self.density_kg_l == WATER_DENSITY_KG_L else
                  f" of a {self.density_kg_l:g} kg/L liquid ({density_flow_factor(self.density_kg_l):.3f} "
                  "times water's)")
        lines = [f"Machine check: the sprayer {verdict}: {rate_text(lo_l)}-{rate_text(hi_l)} {per_area} "
                 f"{also}at {shown_range(self.speed_min_m_s, self.speed_max_m_s, 'm/s', units)} needs "
                 f"{shown_range(self.rpm_min, self.rpm_max, 'L/min', units, '.1f')} of a boom of "
                 f"{self.nozzle!r} nozzles giving "
                 f"{shown_range(self.shaft_rpm_min, self.shaft_rpm_max, 'L/min', units, '.1f')}{liquid}.",
                 self.rates_line(), self.speeds_line(units)]
        if not self.can_apply:
            speeds = shown_range(self.speed_min_m_s, self.speed_max_m_s, "m/s", units)
            sizes = " or ".join(repr(size) for size in self.nozzles_advised)
            lines.append(self.speed_remedy(units))
            lines.append(f"  set [implement] nozzle = {sizes} (now {self.nozzle!r}) to apply it at {speeds}."
                         if sizes else f"  no other nozzle size applies it at {speeds}.")
        return "\n".join(lines)


def check_liquid(scenario):
    """`scenario`'s product, which a sprayer can meter: liquid, of a given density, its calibration
    error the flow meter's (``[implement] flow_meter_error_pct``, not ``[product]
    calibration_error_pct``); `ScenarioError` naming the file, key and value otherwise."""
    product = scenario.product
    if product.form != "liquid":
        raise ScenarioError(f"{scenario.source}: [product] form: a sprayer meters a liquid, got "
                            f"{product.form!r} (set form = \"liquid\" and its density_kg_l)")
    if product.density_kg_l is None:
        raise ScenarioError(f"{scenario.source}: [product] density_kg_l: a sprayer's kg are litres times the "
                            "liquid's density, got none (water: 1.0)")
    if product.calibration_error_pct != 0:
        raise ScenarioError(f"{scenario.source}: [product] calibration_error_pct: a sprayer's calibration "
                            f"error is its flow meter's ([implement] flow_meter_error_pct), got "
                            f"{product.calibration_error_pct!r}")
    return product
