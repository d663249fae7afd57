"""Tuning on the model: the ultimate-gain experiment and a relay auto-tune, both by simulation, and
the fit of the two sensor parameters that close the gap between the paper's model and its experiment.

The paper's transfer functions alone put the 50 ms P loop's phase crossover at the Nyquist frequency
(a 0.1 s oscillation); its measured 0.31 s needs more lag. `fit_sensor` finds the one transport delay
that puts the sampled loop's -180 degree crossing at 2 pi / Tu, and the one sensor gain that makes the
loop gain 1 there at Kp = Ku, from the exact pulse transfer function; `ultimate_gain_experiment` then
checks it the way the paper did it, by raising the gain of a simulated loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller import liang2013
from vrsim.controller.discretize import Lifted, delay_split, lift
from vrsim.controller.gains import GAIN_SOURCES, PidGains, paper_gains, ziegler_nichols
from vrsim.controller.loop import ClosedLoop
from vrsim.controller.loop_io import StepOutput
from vrsim.controller.plant import PlantParams, shaft_rev_row, shaft_rpm_row, state_space, unlimited


def pulse_response(plant: PlantParams, theta: np.ndarray, control_period_s: float = 0.05,
                   delay_s: float | None = None) -> np.ndarray:
    """Pulse transfer function from valve current [A] to sensor reading [rpm] at ``z = exp(j theta)``.

    ``G(z) = z^-d (c Phi_s (z I - Phi_T)^-1 Gamma_T + c Gamma_s)``: exact for the sampled loop with the
    current held over each period and the sensor delay split as in `delay_split`.

    Parameters
    ----------
    theta : ndarray, shape (m,)
        Normalized frequencies omega T [rad], in (0, pi].
    delay_s : float, optional
        Sensor delay to use instead of the plant's [s].
    """
    delay = plant.sensor_delay_s if delay_s is None else delay_s
    A, B = state_space(plant)
    lifted = lift(A, B, shaft_rpm_row(plant), shaft_rev_row(plant), control_period_s, control_period_s,
                  delay)
    nx = A.shape[0]
    phi, gam = lifted.step[:nx, :nx], lifted.step[:nx, nx]
    sample = lifted.step[Lifted.ROW_SAMPLE]
    c_phi_s, c_gam_s = sample[:nx], sample[nx]
    d, _ = delay_split(delay, control_period_s)
    z = np.exp(1j * np.atleast_1d(theta))
    resolvent = np.array([np.linalg.solve(zi * np.eye(nx) - phi, gam) for zi in z])
    return z ** (-d) * (resolvent @ c_phi_s + c_gam_s)


def _phase_at(plant, theta, control_period_s, delay_s):
    """Unwrapped phase of the pulse response at `theta`, unwrapped along a grid from low frequency."""
    grid = np.linspace(1e-4, theta, 400)
    return np.unwrap(np.angle(pulse_response(plant, grid, control_period_s, delay_s)))[-1]


@dataclass(frozen=True)
class SensorFit:
    """Sensor delay and gain that give a P loop with ultimate gain `ku` and period `tu_s`."""

    sensor_delay_s: float
    sensor_gain_v_per_rpm: float
    ku: float
    tu_s: float


def fit_sensor(plant: PlantParams, ku: float, tu_s: float, control_period_s: float = 0.05) -> SensorFit:
    """Fit the speed sensor's transport delay and gain to an ultimate gain `ku` and period `tu_s`.

    The delay solves ``arg G(exp(j 2 pi T / Tu)) = -pi`` (phase falls monotonically with delay), the
    gain ``Ku Ka Ks |G| = 1``. Only the plant's other parameters and T enter.
    """
    theta = 2 * math.pi * control_period_s / tu_s
    if not (0 < theta < math.pi):
        raise ControllerError(f"tu_s must exceed two control periods ({2 * control_period_s} s), "
                              f"got {tu_s!r}")

    def phase_error(delay):
        return _phase_at(plant, theta, control_period_s, delay) + math.pi

    from scipy.optimize import brentq  # scipy.optimize costs ~1 s to import: only when fitting

    if phase_error(0.0) < 0:
        raise ControllerError(f"the plant alone already lags more than 180 degrees at Tu={tu_s!r} s")
    hi = 1.0
    while phase_error(hi) > 0:
        hi *= 2
    delay = brentq(phase_error, 0.0, hi, xtol=1e-12)
    gain = abs(pulse_response(plant, np.array([theta]), control_period_s, delay)[0])
    ks = 1.0 / (ku * plant.amplifier_gain_a_per_v * gain)
    return SensorFit(sensor_delay_s=delay, sensor_gain_v_per_rpm=ks, ku=ku, tu_s=tu_s)


def ultimate_from_pulse(plant: PlantParams, control_period_s: float = 0.05) -> tuple[float, float]:
    """(Ku, Tu) of the sampled P loop from its pulse transfer function: the first -180 degree crossing.

    The frequency-domain counterpart of `ultimate_gain_experiment`, for cross-checks.
    """
    grid = np.linspace(1e-4, math.pi, 2000)
    phase = np.unwrap(np.angle(pulse_response(plant, grid, control_period_s))) + math.pi
    below = np.nonzero(phase <= 0)[0]
    if len(below) == 0:
        raise ControllerError("the sampled P loop never lags 180 degrees: no ultimate gain")
    i = below[0]
    from scipy.optimize import brentq

    if i == 0:
        theta = grid[0]
    else:
        theta = brentq(lambda th: _phase_at(plant, th, control_period_s, plant.sensor_delay_s) + math.pi,
                       grid[i - 1], grid[i])
    gain = abs(pulse_response(plant, np.array([theta]), control_period_s)[0])
    return 1.0 / (plant.amplifier_gain_a_per_v * plant.sensor_gain_v_per_rpm * gain), \
        2 * math.pi * control_period_s / theta


@dataclass(frozen=True)
class UltimateResult:
    """Outcome of an ultimate-gain experiment.

    Attributes
    ----------
    ku : proportional gain at the edge of sustained oscillation [V/V].
    tu_s : period of that oscillation [s].
    growth_per_s : oscillation growth rate at each tried gain [1/s] (negative: decaying).
    gains_tried : the gains of the final sweep [V/V].
    """

    ku: float
    tu_s: float
    gains_tried: np.ndarray
    growth_per_s: np.ndarray


def _run_from_rest(plant: PlantParams, kps, setpoint_rpm: float, duration_s: float, control_period_s: float,
                   plant_step_s: float) -> StepOutput:
    """P loops with gains `kps` (one loop each) stepped from rest to `setpoint_rpm`; per-period records."""
    gains = [PidGains(kp=float(k)) for k in np.atleast_1d(kps)]
    loop = ClosedLoop(plant, gains, control_period_s=control_period_s, plant_step_s=plant_step_s,
                      n=len(gains))
    periods = int(np.ceil(duration_s / control_period_s - 1e-9))
    return loop.run(np.full((periods, len(gains)), setpoint_rpm))


def _mean_speed(res: StepOutput, control_period_s):
    """Shaft speed averaged over each control period [rpm], shape (n, K): exact, free of ringing."""
    return (res.shaft_rev * 60.0 / control_period_s).T


def _growth_rate(y: np.ndarray, dt: float) -> np.ndarray:
    """Growth rate of the oscillation in each row [1/s], from the RMS of its first difference in the
    second and the last quarter of the record (differencing removes the steady level)."""
    dy = np.diff(y, axis=1)
    q = dy.shape[1] // 4
    early = np.sqrt(np.mean(dy[:, q:2 * q] ** 2, axis=1))
    late = np.sqrt(np.mean(dy[:, -q:] ** 2, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.log(late / early) / ((dy.shape[1] - 2 * q) * dt)
    # A loop that has come to rest (down to round-off) is as decaying as it gets.
    at_rest = late <= 1e-9 * np.abs(y).max(axis=1)
    return np.clip(np.where(at_rest | np.isnan(rate), -np.inf, rate), -1e6, 1e6)


def _period(y: np.ndarray, dt: float) -> float:
    """Mean spacing of the upward crossings of the record's mean level, linearly interpolated [s]."""
    z = y - y.mean()
    idx = np.nonzero((z[:-1] < 0) & (z[1:] >= 0))[0]
    if len(idx) < 3:
        raise ControllerError("no sustained oscillation to measure a period from")
    crossings = (idx + z[idx] / (z[idx] - z[idx + 1])) * dt
    return float((crossings[-1] - crossings[0]) / (len(crossings) - 1))


def ultimate_gain_experiment(plant: PlantParams, control_period_s: float = 0.05, plant_step_s: float = 0.001,
                             kp_range: tuple[float, float] = (0.05, 20.0), setpoint_rpm: float = 50.0,
                             duration_s: float = 30.0, sweeps: int = 3, batch: int = 48) -> UltimateResult:
    """Raise a P controller's gain until the loop oscillates steadily, and measure the period.

    Simulated like the paper's experiment (integral off, derivative off) on the unsaturated plant: a
    batch of gains spanning `kp_range` is stepped from rest; each gain's oscillation growth rate comes
    from the simulated shaft speed; the sweep narrows `sweeps` times around the gain where growth
    changes sign. The period is then measured from a run at that gain.
    """
    linear = unlimited(plant)
    lo, hi = kp_range
    gains = np.geomspace(lo, hi, batch)
    for _ in range(sweeps):
        res = _run_from_rest(linear, gains, setpoint_rpm, duration_s, control_period_s, plant_step_s)
        growth = _growth_rate(_mean_speed(res, control_period_s), control_period_s)
        unstable = np.nonzero(growth > 0)[0]
        if len(unstable) == 0 or unstable[0] == 0:
            raise ControllerError(f"no change from decaying to growing oscillation for Kp in {kp_range}")
        i = unstable[0]
        lo, hi = gains[i - 1], gains[i]
        # linear interpolation of the growth rate between the bracketing gains
        ku = lo + (hi - lo) * (-growth[i - 1]) / (growth[i] - growth[i - 1])
        gains_tried, growth_tried = gains, growth
        gains = np.linspace(lo, hi, batch)
    res = _run_from_rest(linear, ku, setpoint_rpm, 3 * duration_s, control_period_s, plant_step_s)
    y = _mean_speed(res, control_period_s)[0]
    tu = _period(y[len(y) // 3:], control_period_s)
    return UltimateResult(ku=float(ku), tu_s=tu, gains_tried=gains_tried, growth_per_s=growth_tried)


@dataclass(frozen=True)
class RelayResult:
    """Astrom-Hagglund relay experiment: Ku = 4 d / (pi a), Tu the limit-cycle period.

    Attributes
    ----------
    ku : estimated ultimate gain [V/V] (controller volts per sensor volt).
    tu_s : limit-cycle period [s].
    relay_amplitude_a : d, the current step either side of the bias [A].
    oscillation_amplitude_rpm : a, half the peak-to-peak of the sensor reading the relay sees [rpm].
    """

    ku: float
    tu_s: float
    relay_amplitude_a: float
    oscillation_amplitude_rpm: float


def relay_autotune(plant: PlantParams, control_period_s: float = 0.05, plant_step_s: float = 0.001,
                   setpoint_rpm: float = 100.0, relay_amplitude_a: float = 0.05,
                   duration_s: float = 20.0) -> RelayResult:
    """Relay auto-tune on the model: the valve current switches between bias +- d at each control tick
    on the sign of the error, and the limit cycle gives Ku and Tu (describing-function estimate).

    The relay is a P loop of very high gain whose current limits are the two relay levels; the bias is
    the current that holds `setpoint_rpm` in steady state.
    """
    if plant is None:
        raise ControllerError("relay auto-tune needs a plant")
    bias = setpoint_rpm / plant.shaft_rpm_per_a
    if not (relay_amplitude_a > 0 and bias - relay_amplitude_a >= 0):
        raise ControllerError(f"relay_amplitude_a must be in (0, {bias:.4g}] A at {setpoint_rpm} rpm, "
                              f"got {relay_amplitude_a!r}")
    relay_plant = replace(plant, current_min_a=bias - relay_amplitude_a,
                          current_max_a=bias + relay_amplitude_a, shaft_rpm_max=setpoint_rpm)
    res = _run_from_rest(relay_plant, 1e9, setpoint_rpm, duration_s, control_period_s, plant_step_s)
    seen = res.measured_rpm[len(res.measured_rpm) // 2:, 0]
    amplitude_rpm = 0.5 * float(seen.max() - seen.min())
    tu = _period(_mean_speed(res, control_period_s)[0][len(seen):], control_period_s)
    d_volts = relay_amplitude_a / plant.amplifier_gain_a_per_v
    a_volts = amplitude_rpm * plant.sensor_gain_v_per_rpm
    return RelayResult(ku=4 * d_volts / (math.pi * a_volts), tu_s=tu, relay_amplitude_a=relay_amplitude_a,
                       oscillation_amplitude_rpm=amplitude_rpm)


def gains_from_source(source: str, terms: str, plant: PlantParams | None = None,
                      control_period_s: float = liang2013.SAMPLE_S, kp: float | None = None,
                      ki: float | None = None, kd: float | None = None) -> PidGains:
    """PID gains from `source` for a controller with `terms` ("P", "PI" or "PID").

    "paper": the paper's printed numbers; "textbook": Ziegler-Nichols from the paper's Ku and Tu;
    "relay": Ziegler-Nichols from `relay_autotune` on `plant`; "manual": `kp` [V/V], `ki` [1/s],
    `kd` [s] as given (missing ones are 0).
    """
    if source == "paper":
        return paper_gains(terms)
    if source == "textbook":
        return ziegler_nichols(terms, liang2013.KU, liang2013.TU_S)
    if source == "relay":
        result = relay_autotune(plant, control_period_s=control_period_s)
        return ziegler_nichols(terms, result.ku, result.tu_s)
    if source == "manual":
        return PidGains(kp=float(kp or 0.0), ki=float(ki or 0.0), kd=float(kd or 0.0))
    raise ControllerError(f"gains must be one of {', '.join(GAIN_SOURCES)}, got {source!r}")
