"""Step-response metrics over a batch of responses, with `control.step_info`'s definitions.

The final value is the last sample (as `step_info` does for data); overshoot and settling are relative
to it, so a P loop with steady-state error is judged around where it settles. Steady-state error and
the integral criteria are against the setpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError


@dataclass(frozen=True)
class StepMetrics:
    """Metrics per response, each an ndarray of shape (n,) (NaN where undefined).

    Attributes
    ----------
    overshoot_pct : peak above the final value, % of the final value.
    rise_s : time from 10% to 90% of the final value [s].
    settling_2pct_s, settling_5pct_s : first time after which the response stays within 2% / 5% of
        the final value [s] (NaN if it never does within the record).
    final : last sample [unit of y].
    steady_state_error : setpoint minus final value [unit of y].
    iae : integral of |setpoint - y| dt [unit of y * s].
    itae : integral of t |setpoint - y| dt [unit of y * s^2].
    """

    overshoot_pct: np.ndarray
    rise_s: np.ndarray
    settling_2pct_s: np.ndarray
    settling_5pct_s: np.ndarray
    final: np.ndarray
    steady_state_error: np.ndarray
    iae: np.ndarray
    itae: np.ndarray

    def row(self, i: int = 0) -> dict[str, float]:
        """Loop `i`'s metrics as plain floats."""
        return {k: float(getattr(self, k)[i]) for k in self.__dataclass_fields__}


def _first_index(mask: np.ndarray) -> np.ndarray:
    """Index of the first True per row; len if none."""
    return np.where(mask.any(axis=1), mask.argmax(axis=1), mask.shape[1])


def _settling(t: np.ndarray, rel: np.ndarray, threshold: float) -> np.ndarray:
    outside = rel >= threshold
    n_t = t.shape[0]
    last = n_t - 1 - np.argmax(outside[:, ::-1], axis=1)
    settled = np.where(outside.any(axis=1), last + 1, 0)
    return np.where(settled < n_t, t[np.minimum(settled, n_t - 1)], np.nan)


def step_metrics(t_s: np.ndarray, y: np.ndarray, setpoint=1.0) -> StepMetrics:
    """Metrics of step responses from rest.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times [s], starting at the step.
    y : ndarray, shape (N,) or (n, N)
        Responses.
    setpoint : float or ndarray (n,)
        Step size, for steady-state error, IAE and ITAE.
    """
    t = np.asarray(t_s, dtype=float)
    y2 = np.atleast_2d(np.asarray(y, dtype=float))
    if t.ndim != 1 or y2.ndim != 2 or y2.shape[1] != t.shape[0] or t.shape[0] < 2:
        raise ControllerError(f"y must have shape (N,) or (n, N) with N = len(t_s) = {t.shape[0]} >= 2, "
                              f"got {np.shape(y)}")
    final = y2[:, -1]
    sgn = np.sign(final)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(y2 / final[:, None] - 1.0)
        lower = _first_index(sgn * (y2 - 0.1 * final[:, None]) >= 0)
        upper = _first_index(sgn * (y2 - 0.9 * final[:, None]) >= 0)
        rise = t[np.minimum(upper, len(t) - 1)] - t[np.minimum(lower, len(t) - 1)]
        peak = np.abs((sgn * y2).max(axis=1))
        overshoot = np.where(peak > np.abs(final), 100.0 * (peak - np.abs(final)) / np.abs(final), 0.0)
    bad = ~np.isfinite(final) | (final == 0)
    err = np.abs(np.asarray(setpoint, dtype=float).reshape(-1, 1) - y2)
    return StepMetrics(
        overshoot_pct=np.where(bad, np.nan, overshoot),
        rise_s=np.where(bad, np.nan, rise),
        settling_2pct_s=np.where(bad, np.nan, _settling(t, rel, 0.02)),
        settling_5pct_s=np.where(bad, np.nan, _settling(t, rel, 0.05)),
        final=final,
        steady_state_error=np.asarray(setpoint, dtype=float) - final,
        iae=np.trapezoid(err, t, axis=1),
        itae=np.trapezoid(err * t, t, axis=1),
    )
