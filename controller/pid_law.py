"""The PID's law, defined once: its linear output and its output stage (saturation, anti-windup).

Every place that runs the paper's PID (Liang et al. 2013, eqs. 13-17) takes its pieces from here:
the lifted-matrix loop (`controller.loop.ClosedLoop`, all its paths), the interface law
(`controller.kinds.pid.PidLaw`, which `smith` builds on) and the kinds with a PID inside (`ff_pi`,
`fuzzy_pid`). One period of the law, in sensor and amplifier volts as in the paper's Fig. 3::

    e = Ks (r - y_m),  y = Ks y_m                              error and reading [V]
    u = row . [acc, e, e1, e2, y, y1, y2]                      unsaturated output [V] (`pid_rows`)
    I = saturate(Ka u, I_min, I_max)                           the valve current held [A]
    incremental: acc <- I / Ka                                 u(n-1) is the *saturated* output
    positional:  acc <- acc + e unless clamped(Ka u, e, ...)   the error sum with clamping

The memory ``acc`` is the anti-windup of both forms: the incremental form remembers the output the
valve really got, so it never winds up beyond a limit; the positional form stops integrating an error
that would push a saturated output further.

`saturate` and `clamped` work on one loop's floats and on n loops' arrays alike (`controller.ops`).
The one-loop path of `ClosedLoop._advance` and the few-loop law of its shared-plant path
(`ClosedLoop._float_law`) write `saturate` out inline (a function call is a tenth of a tick);
`tests/unit/test_controller_law.py` proves them equal to it over random gains, limits and targets.
"""

from __future__ import annotations

import numpy as np


def saturate(unsat_a, lo_a, hi_a, out=None):
    """The valve current the loop applies [A]: the unsaturated output `unsat_a` [A] within
    ``[lo_a, hi_a]``.

    Floats for one loop; arrays of shape (n,) for n loops (bounds scalars or (n,)), written into
    `out` if given.
    """
    if isinstance(unsat_a, np.ndarray):
        return np.minimum(np.maximum(unsat_a, lo_a, out=out), hi_a, out=out)
    return lo_a if unsat_a < lo_a else (hi_a if unsat_a > hi_a else unsat_a)


def clamped(unsat_a, error_v, lo_a, hi_a):
    """Clamping anti-windup: where this period's error stays out of the error sum [bool].

    True where the unsaturated output `unsat_a` [A] lies beyond a current limit and the error
    `error_v` (any unit with the error's sign) would push it further. Floats or arrays (n,).
    """
    return ((unsat_a > hi_a) & (error_v > 0)) | ((unsat_a < lo_a) & (error_v < 0))


def pid_rows(kp: np.ndarray, ki: np.ndarray, kd: np.ndarray, form: str, dom: bool,
             sample_s: float) -> np.ndarray:
    """Coefficients of u(n) on [acc, e, e1, e2, y, y1, y2] (volts), shape (n, 7), from gains (n,):
    kp [V/V], ki [1/s], kd [s]; `dom`: derivative on measurement; `sample_s`: the period T [s]."""
    return _rows_of(np.ones_like(kp), kp, ki * sample_s, kd / sample_s, form, dom)


def pid_terms(kp: np.ndarray, ki: np.ndarray, kd: np.ndarray, form: str, dom: bool,
              sample_s: float) -> tuple[np.ndarray, np.ndarray]:
    """`pid_rows` as (n, 4) weights of (4, 7) basis rows: the rows are linear in (1, kp, ki T, kd / T),
    so the n loops' PID outputs are n weighted sums of four outputs every loop shares."""
    weights = np.column_stack([np.ones_like(kp), kp, ki * sample_s, kd / sample_s])
    return weights, _rows_of(*np.eye(4), form, dom)


def _rows_of(one, kp, ki_t, kd_t, form: str, dom: bool) -> np.ndarray:
    """`pid_rows` of the terms: `one` (1 per loop), kp, ki T and kd / T, each shape (n,)."""
    zero = np.zeros_like(kp)
    if form == "incremental":
        # u(n) = u(n-1) + A e - B e1 + C e2 (paper eq. 16); on measurement D acts on -y.
        if dom:
            cols = (one, kp + ki_t, -kp, zero, -kd_t, 2 * kd_t, -kd_t)
        else:
            cols = (one, kp + ki_t + kd_t, -(kp + 2 * kd_t), kd_t, zero, zero, zero)
    # positional: u(n) = kp e + ki T (sum_{j<n} e + e) + D
    elif dom:
        cols = (ki_t, kp + ki_t, zero, zero, -kd_t, kd_t, zero)
    else:
        cols = (ki_t, kp + ki_t + kd_t, -kd_t, zero, zero, zero, zero)
    return np.column_stack(cols)
