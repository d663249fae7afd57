"""The valve-controlled hydraulic motor of Liang et al. (2013) as a continuous state-space model.

Signal chain (paper Fig. 3, eqs. 1, 2, 11, 12)::

    u [V] --Ka--> I [A] --valve Kq/(s^2/wv^2 + 2 zv s/wv + 1)--> Q [m^3/s]
      --motor (1/Dm)/(s^2/wh^2 + 2 zh s/wh + 1)--> motor speed [rad/s] --1/s--> motor angle [rad]
    metering shaft = transmission_ratio * motor; the speed sensor reports the shaft speed, delayed.

The load torque T_L enters the motor speed through eq. 12 with the paper's (missing) sign restored:
``-(Kce/Dm^2) (1 + Vt/(4 beta_e Kce) s) / (s^2/wh^2 + 2 zh s/wh + 1)``. Both of its coefficients follow
from wh, zh and the total inertia Jt alone (``Kce/Dm^2 = 2 zh/(wh Jt)``, ``Vt/(4 beta_e Kce) =
1/(2 zh wh)``), so the only extra number it needs is Jt.

Where the paper is silent (Dm, the sensor, any delay, the limits) `PlantParams` documents the assumed
value, unit and reason; `docs/model.md` lists them with the measurements they are fitted to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from vrsim.common import ControllerError, check_number

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)

#: Names of the state vector's entries, in order.
STATE_NAMES = ("valve_flow_m3_s", "valve_flow_rate_m3_s2", "motor_speed_rad_s", "motor_speed_aux_rad_s2",
               "motor_angle_rad")
#: Names of the plant's inputs, in order.
INPUT_NAMES = ("current_a", "load_torque_nm")
N_STATES = len(STATE_NAMES)
IX_SPEED = 2
IX_ANGLE = 4
UNLIMITED_A = 1e9   # "no saturation": far beyond any current the linear loop asks for


@dataclass(frozen=True)
class PlantParams:
    """Parameters of the amplifier, valve, motor, transmission, speed sensor and limits.

    Paper values (Liang et al. 2013) unless marked *assumed* or *fitted*; see `ASSUMPTIONS` for the
    reason behind each assumed value.

    Parameters
    ----------
    amplifier_gain_a_per_v : float
        Ka, proportional amplifier gain [A/V] (paper eq. 1: 0.3).
    valve_flow_gain_m3_s_per_a : float
        Kq, valve flow gain [m^3/(s A)] (paper eq. 2: 1.87).
    valve_natural_freq_rad_s, valve_damping : float
        wv [rad/s] and zv [-] of the valve (paper: 335.2, 0.57).
    motor_natural_freq_rad_s, motor_damping : float
        wh [rad/s] and zh [-] of the valve-controlled motor (paper eq. 10: 183.6, 0.12).
    motor_displacement_m3_per_rad : float
        Dm [m^3/rad], *assumed*: chosen so that 1 A drives the unloaded motor at 1250 rpm (Kq/Dm).
    transmission_ratio : float
        Metering-shaft speed / motor speed [-] (paper section 6: 0.2).
    inertia_kg_m2 : float
        Jt, total inertia at the motor shaft [kg m^2], *assumed*; only scales the load-torque path.
    current_min_a, current_max_a : float
        Valve current saturation [A], *assumed* (a 0-1 A proportional-valve coil; a negative minimum
        models a valve that can reverse the motor).
    shaft_rpm_max : float
        Highest metering-shaft speed the loop will be asked for [rpm], *assumed*; targets above it
        are clipped. Must be reachable at `current_max_a`.
    sensor_gain_v_per_rpm : float
        Ks, speed-sensor gain [V/rpm of the metering shaft], *fitted* (with the delay) so that the
        simulated ultimate-gain experiment gives the paper's Ku = 0.955 and Tu = 0.31 s.
    sensor_delay_s : float
        Transport delay of metering shaft and speed sensor [s], *fitted* (see above).
    """

    amplifier_gain_a_per_v: float = 0.3
    valve_flow_gain_m3_s_per_a: float = 1.87
    valve_natural_freq_rad_s: float = 335.2
    valve_damping: float = 0.57
    motor_natural_freq_rad_s: float = 183.6
    motor_damping: float = 0.12
    motor_displacement_m3_per_rad: float = 0.0142857
    transmission_ratio: float = 0.2
    inertia_kg_m2: float = 0.02
    current_min_a: float = 0.0
    current_max_a: float = 1.0
    shaft_rpm_max: float = 200.0
    sensor_gain_v_per_rpm: float = 0.0139936
    sensor_delay_s: float = 0.104215

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            check_number(value, f"plant {f.name}", ControllerError)
            if f.name == "current_min_a":
                continue  # may be negative: a valve that can reverse the motor
            nonneg = f.name == "sensor_delay_s"
            if (value < 0) if nonneg else (value <= 0):
                sign = ">= 0" if nonneg else "> 0"
                raise ControllerError(f"plant {f.name} must be {sign}, got {value!r}")
        if self.current_max_a <= self.current_min_a:
            raise ControllerError(f"plant current_max_a must exceed current_min_a "
                                  f"({self.current_min_a!r}), got {self.current_max_a!r}")
        reachable = self.shaft_rpm_per_a * self.current_max_a
        if self.shaft_rpm_max > reachable:
            raise ControllerError(f"plant shaft_rpm_max {self.shaft_rpm_max!r} cannot be reached: "
                                  f"current_max_a {self.current_max_a!r} gives only {reachable:.4g} rpm")

    @property
    def shaft_rpm_per_a(self) -> float:
        """Steady-state metering-shaft speed per ampere of valve current [rpm/A], no load."""
        return (self.valve_flow_gain_m3_s_per_a / self.motor_displacement_m3_per_rad
                * self.transmission_ratio * RPM_PER_RAD_S)

    @property
    def load_droop_rad_s_per_nm(self) -> float:
        """Kce/Dm^2 = 2 zh / (wh Jt): steady motor-speed loss per N m of load torque [rad/s/(N m)]."""
        return 2.0 * self.motor_damping / (self.motor_natural_freq_rad_s * self.inertia_kg_m2)

    @property
    def load_lead_s(self) -> float:
        """Vt/(4 beta_e Kce) = 1/(2 zh wh): time constant of eq. 12's numerator [s]."""
        return 1.0 / (2.0 * self.motor_damping * self.motor_natural_freq_rad_s)

    def loop_gain_per_controller_gain(self) -> float:
        """DC gain from controller output to sensor voltage, Ka Ks (shaft rpm per A) [V/V]."""
        return self.amplifier_gain_a_per_v * self.sensor_gain_v_per_rpm * self.shaft_rpm_per_a


#: Why each value the paper does not give was chosen: (unit, reason). `assumptions` adds the values.
ASSUMPTIONS = {
    "motor_displacement_m3_per_rad": (
        "m^3/rad", "Not in the paper. Only Kq/Dm matters; chosen so 1 A drives the unloaded motor at "
        "1250 rpm (shaft 250 rpm at ratio 0.2, 25% above shaft_rpm_max). The paper's Kq = 1.87 m^3/(s A) "
        "is about 10^4 times a real valve's, so Dm is scaled alike; the loop only sees Ka Ks Kq/Dm, "
        "which the sensor fit absorbs."),
    "sensor_gain_v_per_rpm": (
        "V/rpm", "Not in the paper. Fitted together with sensor_delay_s so that vrsim's simulated "
        "ultimate-gain experiment gives the paper's Ku = 0.955 (controller.tuning.fit_sensor)."),
    "sensor_delay_s": (
        "s", "Not in the paper. Transport delay of metering shaft and pulse-counting speed sensor, fitted "
        "so the simulated experiment oscillates with the paper's Tu = 0.31 s. Without it the paper's "
        "transfer functions (resonances at 184 and 335 rad/s) make the 50 ms P loop oscillate at the "
        "Nyquist frequency, a 0.1 s period."),
    "inertia_kg_m2": (
        "kg m^2", "Not in the paper. Motor rotor plus reflected metering shaft; only scales the load-torque "
        "path of eq. 12 (droop Kce/Dm^2 = 2 zh/(wh Jt)), which is zero unless a load torque is applied."),
    "current_min_a": ("A", "Not in the paper. A 0-1 A proportional-valve coil; no reverse flow."),
    "current_max_a": ("A", "Not in the paper. A 0-1 A proportional-valve coil."),
    "shaft_rpm_max": (
        "rpm", "Not in the paper. The default field (12 m, 2.5 m/s, 0.5 kg/rev) needs 108 rpm at "
        "300 kg/ha; 200 rpm allows up to 555 kg/ha."),
}


def assumptions(p: PlantParams) -> dict[str, dict]:
    """The assumed and fitted parameters of `p`: {name: {"value", "unit", "why"}}."""
    return {name: {"value": getattr(p, name), "unit": unit, "why": why}
            for name, (unit, why) in ASSUMPTIONS.items()}


def state_space(p: PlantParams) -> tuple[np.ndarray, np.ndarray]:
    """Continuous model ``dx/dt = A x + B [current_a, load_torque_nm]``.

    States are `STATE_NAMES`: the valve in controllable form, the motor speed in observable form (so
    that eq. 12's derivative of the load torque needs no derivative of the input), and the motor angle.

    Returns
    -------
    A : ndarray, shape (5, 5)
    B : ndarray, shape (5, 2)
    """
    wv, zv = p.valve_natural_freq_rad_s, p.valve_damping
    wh, zh = p.motor_natural_freq_rad_s, p.motor_damping
    lead = wh**2 * p.load_droop_rad_s_per_nm * p.load_lead_s   # b1 of the load numerator
    droop = wh**2 * p.load_droop_rad_s_per_nm                   # b0 of the load numerator
    A = np.zeros((N_STATES, N_STATES))
    B = np.zeros((N_STATES, 2))
    A[0, 1] = 1.0
    A[1, 0], A[1, 1] = -wv**2, -2.0 * zv * wv
    B[1, 0] = wv**2 * p.valve_flow_gain_m3_s_per_a
    A[2, 3] = 1.0
    B[2, 1] = -lead
    A[3, 0] = wh**2 / p.motor_displacement_m3_per_rad
    A[3, 2], A[3, 3] = -wh**2, -2.0 * zh * wh
    B[3, 1] = 2.0 * zh * wh * lead - droop
    A[4, 2] = 1.0
    return A, B


def shaft_rpm_row(p: PlantParams) -> np.ndarray:
    """Row vector c with ``c @ x`` = metering-shaft speed [rpm], shape (5,)."""
    c = np.zeros(N_STATES)
    c[IX_SPEED] = p.transmission_ratio * RPM_PER_RAD_S
    return c


def shaft_rev_row(p: PlantParams) -> np.ndarray:
    """Row vector c with ``c @ x`` = metering-shaft angle [rev], shape (5,)."""
    c = np.zeros(N_STATES)
    c[IX_ANGLE] = p.transmission_ratio / (2.0 * math.pi)
    return c


def unlimited(plant: PlantParams) -> PlantParams:
    """The same plant without current saturation: the linear model the paper simulates."""
    rpm_max = max(plant.shaft_rpm_max, plant.shaft_rpm_per_a * UNLIMITED_A / 2)
    return replace(plant, current_min_a=-UNLIMITED_A, current_max_a=UNLIMITED_A, shaft_rpm_max=rpm_max)
