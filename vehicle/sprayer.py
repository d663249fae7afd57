"""The sprayer's boom: ISO 10625 nozzles, their pressure range as the machine's limit, the flow meter,
and per-nozzle pulse-width modulation (PWM) with turn compensation.

A nozzle's flow follows the square root of its pressure, ``q = q_ref sqrt(p / p_ref)``, with ``q_ref``
the ISO 10625 size's flow at ``p_ref = 3 bar`` (an ``02`` gives 0.8 L/min). Its pressure range
bounds the flow of each nozzle, and so the speeds at which a rate (L/ha) can be applied: a nozzle
``spacing`` metres apart must give ``rate * speed * spacing * 0.006`` L/min. The boom's target flow is
``rate [L/ha] * speed [m/s] * width [m] * 60 / 10 000`` L/min (m^2/s over 10 000 m^2/ha, times 60 s/min).

The ratings are for water. A nozzle is an orifice, ``q = C A sqrt(2 dp / rho)``: at the same pressure
it passes ``sqrt(1 / SG)`` times its water flow of a liquid of specific gravity ``SG = rho / 1 kg/L``
(`density_flow_factor`, the catalogues' conversion factor: UAN 28 % at 1.28 kg/L, 0.884). Every flow
at a pressure here (`nozzle_flow_l_min`, and through it the flow range, speeds, nozzle advice and
PWM's open flow) takes the liquid's density; none given is water's.

The flow meter counts pulses; the terminal divides them by the configured pulses per litre, while
the meter's true constant differs by its calibration error: the controller sees the meter's flow,
the ground gets the true flow.

PWM (``control = "pwm"``): the pump loop holds the boom at ``pwm_pressure_bar`` and each nozzle's
solenoid opens for a duty cycle of each pulse period, so its mean flow is ``duty * q(p)``. In a turn
each nozzle moves at its own ground speed ``v + yaw_rate * offset`` (offset to the right of the
boom's centre: the left nozzles are inside a left, counter-clockwise turn), and turn compensation
scales each nozzle's duty by it. Arrays over ticks and nozzles have shape (K, N), nozzles from left
to right.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from vrsim.common.checks import check_number, check_positive, in_range
from vrsim.common.errors import VehicleError
from vrsim.vehicle.machines import MachineSpec, register_spec

__all__ = ["NOZZLE_FLOW_L_MIN", "WATER_DENSITY_KG_L", "FlowMeter", "SprayerSpec", "applied_rate_l_ha",
           "boom_flow_l_min", "density_flow_factor", "nozzle_flow_l_min", "nozzle_pressure_bar",
           "nozzle_speeds_m_s", "pwm_duty_pct", "pwm_open_fraction", "pwm_phases"]

#: ISO 10625 size code -> nominal flow at `REF_PRESSURE_BAR` [L/min].
NOZZLE_FLOW_L_MIN = {"01": 0.4, "015": 0.6, "02": 0.8, "025": 1.0, "03": 1.2, "04": 1.6, "05": 2.0,
                     "06": 2.4, "08": 3.2}
REF_PRESSURE_BAR = 3.0
WATER_DENSITY_KG_L = 1.0   # the liquid of the ratings: specific gravity is a density over this
L_HA_M2_PER_L_MIN_S = 10_000.0 / 60.0   # rate [L/ha] * speed [m/s] * width [m] / this = flow [L/min]
VALVES = ("bypass", "inline")
CONTROLS = ("flow", "pwm")
PWM_HZ_RANGE = (10.0, 30.0)
FLOW_METER_ERROR_MAX_PCT = 50.0   # a meter further off than this is a typo, not a calibration


def density_flow_factor(density_kg_l: float | None = None) -> float:
    """A nozzle's flow of a liquid of `density_kg_l` [kg/L] over its flow of water at the same pressure
    [-]: ``sqrt(1 / SG)``, ``SG = density_kg_l / WATER_DENSITY_KG_L`` (an orifice passes ``q = C A
    sqrt(2 dp / rho)``; nozzle catalogues' conversion factor for solutions other than water, e.g.
    TeeJet's 0.88 for 28 % N at 1.28). The one place the density enters a nozzle's flow.

    None (the product's density not stated) is taken as water: 1.0, as is a density of 1.0, exactly.
    """
    if density_kg_l is None:
        return 1.0
    check_positive(density_kg_l, "sprayer: the liquid's density_kg_l", VehicleError, unit="kg/L")
    return math.sqrt(WATER_DENSITY_KG_L / density_kg_l)


def nozzle_flow_l_min(q_ref_l_min, pressure_bar, density_kg_l: float | None = None):
    """Flow of a nozzle rated `q_ref_l_min` of water at 3 bar, at `pressure_bar` [L/min], of a liquid of
    `density_kg_l` [kg/L] (None: water): the square-root law times `density_flow_factor`."""
    return (np.asarray(q_ref_l_min, float) * density_flow_factor(density_kg_l)
            * np.sqrt(np.asarray(pressure_bar, float) / REF_PRESSURE_BAR))


def nozzle_pressure_bar(q_ref_l_min, flow_l_min, density_kg_l: float | None = None):
    """Pressure at which a nozzle rated `q_ref_l_min` of water at 3 bar gives `flow_l_min` [bar] of a
    liquid of `density_kg_l` [kg/L] (None: water): the inverse of `nozzle_flow_l_min`."""
    q_ref = nozzle_flow_l_min(q_ref_l_min, REF_PRESSURE_BAR, density_kg_l)
    return REF_PRESSURE_BAR * (np.asarray(flow_l_min, float) / q_ref) ** 2


def boom_flow_l_min(rate_l_ha, speed_m_s, width_m):
    """Flow that applies `rate_l_ha` [L/ha] at `speed_m_s` [m/s] over `width_m` [m], in L/min."""
    return np.asarray(rate_l_ha, float) * np.asarray(speed_m_s, float) * np.asarray(width_m, float) \
        / L_HA_M2_PER_L_MIN_S


def applied_rate_l_ha(flow_l_min, speed_m_s, width_m):
    """Rate [L/ha] that `flow_l_min` lays over a strip `width_m` wide moving at `speed_m_s`.

    The inverse of `boom_flow_l_min`; a nozzle moving backwards (beyond the centre of a tight turn)
    covers ground too, so the speed's magnitude counts. NaN where the strip does not move.
    """
    ground = np.abs(np.asarray(speed_m_s, float)) * np.asarray(width_m, float)
    flow = np.asarray(flow_l_min, float) * L_HA_M2_PER_L_MIN_S
    return np.divide(flow, ground, out=np.full(np.broadcast(flow, ground).shape, np.nan), where=ground > 0)


@dataclass(frozen=True)
class FlowMeter:
    """A pulse flow meter and the constant the terminal was told.

    Attributes
    ----------
    pulses_per_l : float
        The configured constant: the terminal's litres are pulses / `pulses_per_l`.
    error_pct : float
        Calibration error: the meter's true constant is ``pulses_per_l * (1 + error_pct / 100)``, so
        it reads `error_pct` % more than flows (a controller holding its reading on target under-applies).
    """

    pulses_per_l: float = 600.0
    error_pct: float = 0.0

    def __post_init__(self):
        check_positive(self.pulses_per_l, "sprayer: flow_meter_pulses_per_l", VehicleError)
        check_number(self.error_pct, "sprayer: flow_meter_error_pct", VehicleError,
                     lo=-FLOW_METER_ERROR_MAX_PCT, hi=FLOW_METER_ERROR_MAX_PCT, unit="%")

    @property
    def gain(self) -> float:
        """Metered litres per true litre [-]."""
        return 1.0 + self.error_pct / 100.0

    def pulses(self, true_l_total):
        """Whole pulses counted by the time `true_l_total` litres have flowed (cumulative) [-]."""
        return np.floor(np.asarray(true_l_total, float) * self.pulses_per_l * self.gain + 1e-9)

    def metered_l(self, true_l_total):
        """Litres the terminal counts (cumulative, whole pulses) once `true_l_total` litres have flowed."""
        return self.pulses(true_l_total) / self.pulses_per_l

    def true_l(self, metered_l):
        """True litres [L] (or L/min) behind a metered amount (or flow), before pulse rounding."""
        return np.asarray(metered_l, float) / self.gain


@register_spec
@dataclass(frozen=True)
class SprayerSpec(MachineSpec):
    """The sprayer kind's own ``[implement]`` keys (``kind = "sprayer"``, `vehicle.machines`).

    Attributes
    ----------
    nozzle : str
        ISO 10625 size code (`NOZZLE_FLOW_L_MIN`): "01", "015", "02", "025", "03", "04", "05", "06", "08".
    nozzle_spacing_m : float
        Distance between nozzles along the boom [m].
    pressure_range_bar : tuple of float
        The nozzle's working pressures (low, high) [bar]: the machine's limit. The flows they give depend
        on the liquid (`density_flow_factor`): the methods below take its ``density_kg_l`` (None: water).
    flow_meter_pulses_per_l : float
        The flow meter's configured constant [pulses/L].
    flow_meter_error_pct : float
        Its calibration error [%] (`FlowMeter`).
    valve : {"bypass", "inline"}
        The regulating valve: in the pump's return line, or in line with the boom.
    control : {"flow", "pwm"}
        Flow control by the valve (pressure varies), or pressure held and per-nozzle PWM.
    pwm_hz : float
        PWM frequency [Hz], 10 to 30.
    duty_range_pct : tuple of float
        Lowest and highest duty cycle a nozzle's solenoid can hold [%].
    pwm_pressure_bar : float
        The pressure the pump loop holds under PWM [bar], within `pressure_range_bar`.
    """

    KIND: ClassVar[str] = "sprayer"
    # A boom has no metering shaft: its flow meter and nozzles stand for these.
    UNUSED_KEYS: ClassVar[tuple[str, ...]] = ("kg_per_rev", "transmission_ratio", "shaft_rpm_min",
                                              "shaft_rpm_max")

    nozzle: str = "02"
    nozzle_spacing_m: float = 0.5
    pressure_range_bar: tuple[float, float] = (1.5, 5.0)
    flow_meter_pulses_per_l: float = 600.0
    flow_meter_error_pct: float = 0.0
    valve: str = "bypass"
    control: str = "flow"
    pwm_hz: float = 15.0
    duty_range_pct: tuple[float, float] = (10.0, 100.0)
    pwm_pressure_bar: float = 3.0

    def __post_init__(self):
        if not isinstance(self.nozzle, str) or self.nozzle not in NOZZLE_FLOW_L_MIN:
            raise VehicleError(f"sprayer: nozzle must be one of {', '.join(NOZZLE_FLOW_L_MIN)} "
                               f"(ISO 10625), got {self.nozzle!r}")
        check_positive(self.nozzle_spacing_m, "sprayer: nozzle_spacing_m", VehicleError, unit="m")
        object.__setattr__(self, "pressure_range_bar", _pair(self.pressure_range_bar, "pressure_range_bar"))
        object.__setattr__(self, "duty_range_pct", _pair(self.duty_range_pct, "duty_range_pct", hi=100.0))
        for name, choices in (("valve", VALVES), ("control", CONTROLS)):
            if getattr(self, name) not in choices:
                raise VehicleError(f"sprayer: {name} must be one of {', '.join(choices)}, "
                                   f"got {getattr(self, name)!r}")
        check_number(self.pwm_hz, "sprayer: pwm_hz", VehicleError, lo=PWM_HZ_RANGE[0], hi=PWM_HZ_RANGE[1],
                     unit="Hz")
        if self.control == "pwm":
            lo, hi = self.pressure_range_bar
            check_number(self.pwm_pressure_bar, "sprayer: pwm_pressure_bar", VehicleError, lo=lo, hi=hi,
                         unit="bar (the nozzle's pressure_range_bar)")
        FlowMeter(self.flow_meter_pulses_per_l, self.flow_meter_error_pct)   # checks its two keys

    @property
    def q_ref_l_min(self) -> float:
        """The nozzle's rated flow of water at 3 bar [L/min] (`rated_flow_l_min`: of a liquid)."""
        return NOZZLE_FLOW_L_MIN[self.nozzle]

    def rated_flow_l_min(self, density_kg_l: float | None = None) -> float:
        """The nozzle's flow at 3 bar of a liquid of `density_kg_l` [L/min] (None: water's rating)."""
        return float(nozzle_flow_l_min(self.q_ref_l_min, REF_PRESSURE_BAR, density_kg_l))

    @property
    def meter(self) -> FlowMeter:
        """The boom's flow meter."""
        return FlowMeter(self.flow_meter_pulses_per_l, self.flow_meter_error_pct)

    def nozzle_flow_range_l_min(self, nozzle: str | None = None,
                                density_kg_l: float | None = None) -> tuple[float, float]:
        """Lowest and highest mean flow of one nozzle [L/min] (of size `nozzle`, default this one's) of a
        liquid of `density_kg_l` [kg/L] (None: water).

        Flow control: the flows at the ends of the pressure range. PWM: the duty range at the held
        pressure.
        """
        q_ref = NOZZLE_FLOW_L_MIN[nozzle or self.nozzle]
        if self.control == "pwm":
            q = float(nozzle_flow_l_min(q_ref, self.pwm_pressure_bar, density_kg_l))
            return q * self.duty_range_pct[0] / 100.0, q * self.duty_range_pct[1] / 100.0
        lo, hi = nozzle_flow_l_min(q_ref, self.pressure_range_bar, density_kg_l)
        return float(lo), float(hi)

    def nozzle_count(self, width_m: float) -> int:
        """Nozzles on a boom `width_m` wide (one per `nozzle_spacing_m`); the width must be a whole
        number of spacings (to 1 %)."""
        count = width_m / self.nozzle_spacing_m
        if round(count) < 1 or abs(count - round(count)) > 0.01:
            raise VehicleError(f"sprayer: nozzle_spacing_m {self.nozzle_spacing_m!r} does not divide the "
                               f"working width {width_m!r} m into whole nozzles")
        return round(count)

    def nozzle_offsets_m(self, width_m: float) -> np.ndarray:
        """Each nozzle's lateral offset from the boom's centre, left to right, positive right [m], (N,)."""
        n = self.nozzle_count(width_m)
        return (np.arange(n) - (n - 1) / 2.0) * self.nozzle_spacing_m

    def speed_range_m_s(self, rate_min_l_ha: float, rate_max_l_ha: float | None = None,
                        nozzle: str | None = None,
                        density_kg_l: float | None = None) -> tuple[float, float] | None:
        """Speeds [m/s] at which every rate in [min, max] (L/ha, > 0) of a liquid of `density_kg_l`
        (kg/L; None: water) keeps the nozzles in range.

        None when no speed does (the nozzle's flow ratio is narrower than the rates'); `nozzle`
        tries another size on this boom.
        """
        rate_max = rate_min_l_ha if rate_max_l_ha is None else rate_max_l_ha
        check_positive(rate_min_l_ha, "sprayer: lowest rate", VehicleError, unit="L/ha")
        check_number(rate_max, "sprayer: highest rate", VehicleError, lo=rate_min_l_ha, unit="L/ha")
        q_lo, q_hi = self.nozzle_flow_range_l_min(nozzle, density_kg_l)
        per_speed = self.nozzle_spacing_m / L_HA_M2_PER_L_MIN_S     # L/min per (L/ha * m/s)
        v_lo, v_hi = q_lo / (rate_min_l_ha * per_speed), q_hi / (rate_max * per_speed)
        return (v_lo, v_hi) if v_lo <= v_hi else None

    def suggest_nozzle(self, rate_min_l_ha: float, rate_max_l_ha: float, speed_m_s: float,
                       density_kg_l: float | None = None) -> str | None:
        """The ISO size that covers rates [min, max] (L/ha) of a liquid of `density_kg_l` (kg/L; None:
        water) at `speed_m_s` with the most margin (the needed flows centred in its range, in log
        terms), or None if no size does."""
        check_positive(speed_m_s, "sprayer: working speed", VehicleError, unit="m/s")
        best, best_margin = None, -math.inf
        for size in NOZZLE_FLOW_L_MIN:
            span = self.speed_range_m_s(rate_min_l_ha, rate_max_l_ha, size, density_kg_l)
            if span is not None and span[0] <= speed_m_s <= span[1]:
                margin = min(math.log(speed_m_s / span[0]), math.log(span[1] / speed_m_s))
                if margin > best_margin:
                    best, best_margin = size, margin
        return best

    def nozzles_for(self, rate_min_l_ha: float, rate_max_l_ha: float, speed_range_m_s: tuple[float, float],
                    density_kg_l: float | None = None) -> list[str]:
        """The ISO sizes other than this one that cover rates [min, max] (L/ha) of a liquid of
        `density_kg_l` (kg/L; None: water) at every speed of `speed_range_m_s` (m/s): the nearest
        smaller and the nearest larger that do (by rated flow), the nearer first; empty if none does."""
        v_lo, v_hi = speed_range_m_s
        fits = []
        for size in NOZZLE_FLOW_L_MIN:
            span = self.speed_range_m_s(rate_min_l_ha, rate_max_l_ha, size, density_kg_l)
            if size != self.nozzle and span is not None and span[0] <= v_lo and v_hi <= span[1]:
                fits.append(size)
        q_ref = self.q_ref_l_min
        smaller = [s for s in fits if NOZZLE_FLOW_L_MIN[s] < q_ref]
        larger = [s for s in fits if NOZZLE_FLOW_L_MIN[s] > q_ref]
        nearest = smaller[-1:] + larger[:1]   # the table runs from the smallest size up
        return sorted(nearest, key=lambda s: abs(math.log(NOZZLE_FLOW_L_MIN[s] / q_ref)))

    def check_rates(self, rate_min_l_ha: float, rate_max_l_ha: float,
                    density_kg_l: float | None = None) -> tuple[float, float]:
        """The speed range of `speed_range_m_s` (a liquid of `density_kg_l`, None: water); a
        `VehicleError` naming the nozzle when there is none."""
        span = self.speed_range_m_s(rate_min_l_ha, rate_max_l_ha, density_kg_l=density_kg_l)
        if span is None:
            q_lo, q_hi = self.nozzle_flow_range_l_min(density_kg_l=density_kg_l)
            raise VehicleError(f"sprayer: nozzle {self.nozzle!r} ({q_lo:.3g}-{q_hi:.3g} L/min per nozzle) "
                               f"cannot apply {rate_min_l_ha:g}-{rate_max_l_ha:g} L/ha at any speed: the "
                               f"rates span {rate_max_l_ha / rate_min_l_ha:.3g}x, the nozzle "
                               f"{q_hi / q_lo:.3g}x (widen pressure_range_bar, or control = \"pwm\")")
        return span


def _pair(value, key: str, hi: float | None = None) -> tuple[float, float]:
    """A (low, high) pair of numbers with 0 < low < high (<= `hi`), or a `VehicleError` naming `key`."""
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(in_range(v, 0.0, hi, lo_open=True) for v in value)
          and value[0] < value[1])
    if not ok:
        raise VehicleError(f"sprayer: {key} must be [low, high] with 0 < low < high"
                           f"{f' <= {hi:g}' if hi else ''}, got {value!r}")
    return float(value[0]), float(value[1])


# --- PWM -----------------------------------------------------------------------------------------------
def nozzle_speeds_m_s(speed_m_s, yaw_rate_rad_s, offsets_m) -> np.ndarray:
    """Each nozzle's ground speed ``v + yaw_rate * offset`` [m/s], (K, N).

    `speed_m_s`, `yaw_rate_rad_s` (K,) (yaw rate counter-clockwise positive); `offsets_m` (N,) to the
    right of the boom's centre (`SprayerSpec.nozzle_offsets_m`).
    """
    v = np.asarray(speed_m_s, float).reshape(-1, 1)
    w = np.asarray(yaw_rate_rad_s, float).reshape(-1, 1)
    return v + w * np.asarray(offsets_m, float)[None, :]


def pwm_duty_pct(rate_l_ha, nozzle_speed_m_s, spacing_m: float, nozzle_flow_l_min: float,
                 duty_range_pct: tuple[float, float]) -> np.ndarray:
    """Duty cycle of each nozzle [%], (K, N): what applies `rate_l_ha` at its own speed, clipped to the
    duty range (the limit); 0 where the rate is 0 (off).

    Parameters
    ----------
    rate_l_ha : array, (K,) or (K, N)
        Target rate [L/ha].
    nozzle_speed_m_s : array, (K, N)
        Ground speed used for each nozzle [m/s]: `nozzle_speeds_m_s` (turn compensation) or the boom
        centre's speed broadcast (none).
    spacing_m : float
        Nozzle spacing [m].
    nozzle_flow_l_min : float
        A fully open nozzle's flow at the held pressure [L/min], of the liquid sprayed
        (`nozzle_flow_l_min` with its density).
    duty_range_pct : (float, float)
        The solenoid's lowest and highest duty [%].
    """
    rate = np.asarray(rate_l_ha, float)
    rate = rate[:, None] if rate.ndim == 1 else rate
    need = boom_flow_l_min(rate, np.abs(nozzle_speed_m_s), spacing_m) / nozzle_flow_l_min * 100.0
    return np.where(rate > 0, np.clip(need, *duty_range_pct), 0.0)


def pwm_phases(n_nozzles: int) -> np.ndarray:
    """Pulse phase of each nozzle [fraction of a period], (N,): neighbours alternate by half a period,
    as PWM booms fire them, so the boom's total flow stays steady."""
    return np.where(np.arange(n_nozzles) % 2 == 1, 0.5, 0.0)


def pwm_open_fraction(duty_pct, t_start_s, tick_s: float, pwm_hz: float, phases) -> np.ndarray:
    """Share of each tick each nozzle's solenoid is open, (K, N), from its pulse train.

    A nozzle is open while ``frac(pwm_hz * t + phase) < duty``; the open time up to t is
    ``floor(u) d + min(frac(u), d)`` with ``u = pwm_hz t + phase``, exact for a duty held over the tick.
    Over many ticks it averages to the duty; within a tick shorter than a pulse period it does not.

    Parameters
    ----------
    duty_pct : array, (K, N)
        Duty held over each tick [%].
    t_start_s : array, (K,)
        Each tick's start [s]; the tick lasts `tick_s`.
    pwm_hz : float
        Pulse frequency [Hz].
    phases : array, (N,)
        Each nozzle's phase (`pwm_phases`).
    """
    d = np.asarray(duty_pct, float) / 100.0
    t0 = np.asarray(t_start_s, float)[:, None]

    def open_time(t):   # pulse periods open since u = 0
        u = pwm_hz * t + np.asarray(phases, float)[None, :]
        return np.floor(u) * d + np.minimum(u - np.floor(u), d)

    return (open_time(t0 + tick_s) - open_time(t0)) / (pwm_hz * tick_s)
