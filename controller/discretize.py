"""Exact zero-order-hold discretization and its lifting over one control period.

The controller holds its output for a whole control period T, so the plant over T is exactly one
ZOH step of length T; the 1 ms samples inside the period (the paper's 1 kHz bench) are exactly
``x(j h) = Phi(j h) x0 + Gamma(j h) u`` for j = 1..N. `Lifted` precomputes all of them, plus the
state at the sensor's fractional delay instant, so one control period costs one small matrix product
instead of N fine steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError, check_positive

__all__ = ["zoh", "fine_steps", "delay_split", "Lifted", "lift"]


def zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretization over `h` seconds via the augmented matrix exponential.

    Parameters
    ----------
    A : ndarray, shape (nx, nx)
    B : ndarray, shape (nx, nu)
    h : float
        Step [s], >= 0.

    Returns
    -------
    Phi : ndarray, shape (nx, nx)
        ``exp(A h)``.
    Gamma : ndarray, shape (nx, nu)
        ``integral_0^h exp(A s) ds B``.
    """
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx] = A * h
    M[:nx, nx:] = B * h
    from scipy.linalg import expm  # here, not at import: a scenario loads without scipy

    E = expm(M)
    return E[:nx, :nx], E[:nx, nx:]


def fine_steps(control_period_s: float, plant_step_s: float) -> int:
    """Number of plant steps per control period; the period must be a whole multiple of the step."""
    check_positive(plant_step_s, "plant_step_s", ControllerError)
    if not (math.isfinite(control_period_s) and control_period_s >= plant_step_s):
        raise ControllerError(f"control_period_s must be >= plant_step_s ({plant_step_s!r}), "
                              f"got {control_period_s!r}")
    n = round(control_period_s / plant_step_s)
    if abs(n * plant_step_s - control_period_s) > 1e-9 * control_period_s:
        raise ControllerError(f"control_period_s {control_period_s!r} is not a whole multiple of "
                              f"plant_step_s {plant_step_s!r}")
    return n


def delay_split(delay_s: float, control_period_s: float) -> tuple[int, float]:
    """Split a sensor delay into whole periods d >= 1 and an offset s in (0, T].

    The reading used at tick k is the output at ``k T - delay = (k - d) T + s``, i.e. inside period
    k - d, computable from that period's start state and held input.
    """
    d = math.floor(delay_s / control_period_s + 1e-12) + 1
    return d, d * control_period_s - delay_s


@dataclass(frozen=True)
class Lifted:
    """One control period of the plant, lifted into matrices on ``z = [x, u]`` (shape nx + nu).

    Attributes
    ----------
    step : ndarray, shape (nx + 3, nx + nu)
        Rows: next state (nx), shaft revolutions over the period, the sensor sample at the delay
        offset, and the shaft speed at the period's end [rpm].
    fine : ndarray, shape (N, nx + nu)
        Shaft speed [rpm] at the N plant steps inside the period (the last one is the period's end).
    delay_periods : int
        d: whole periods between taking a sensor sample and the PID using it.
    """

    step: np.ndarray
    fine: np.ndarray
    delay_periods: int

    ROW_REV = -3
    ROW_SAMPLE = -2
    ROW_RPM = -1


def lift(A: np.ndarray, B: np.ndarray, c_rpm: np.ndarray, c_rev: np.ndarray, control_period_s: float,
         plant_step_s: float, delay_s: float) -> Lifted:
    """Precompute the lifted matrices of one control period.

    Parameters
    ----------
    A, B : ndarray
        Continuous model, shapes (nx, nx) and (nx, nu).
    c_rpm, c_rev : ndarray, shape (nx,)
        Output rows: shaft speed [rpm] and shaft angle [rev].
    control_period_s, plant_step_s, delay_s : float
        Control period T, fine step h (T = N h) and sensor delay [s].
    """
    n_fine = fine_steps(control_period_s, plant_step_s)
    nx, nu = B.shape
    phi_h, gam_h = zoh(A, B, plant_step_s)
    fine = np.empty((n_fine, nx + nu))
    phi, gam = np.eye(nx), np.zeros((nx, nu))
    for j in range(n_fine):
        phi, gam = phi_h @ phi, phi_h @ gam + gam_h
        fine[j] = c_rpm @ np.hstack([phi, gam])
    # The period's end is one exact ZOH step of length T (not N accumulated fine steps).
    phi_t, gam_t = zoh(A, B, control_period_s)
    d, s = delay_split(delay_s, control_period_s)
    phi_s, gam_s = zoh(A, B, s)
    step = np.vstack([
        np.hstack([phi_t, gam_t]),
        c_rev @ np.hstack([phi_t - np.eye(nx), gam_t]),
        c_rpm @ np.hstack([phi_s, gam_s]),
        c_rpm @ np.hstack([phi_t, gam_t]),
    ])
    return Lifted(step=step, fine=fine, delay_periods=d)
