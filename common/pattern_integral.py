"""The integral of a piecewise-linear transverse pattern, exact: one function for the machine's keys
(`vehicle.spinner.TransversePattern`) and the deposition's footprint (`maps.SpinnerThrow`), which
may not import each other, so it lives here, below both.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cumulative_mass"]


def cumulative_mass(offset_m: np.ndarray, mass_per_m: np.ndarray, at_m) -> np.ndarray:
    """A pattern's mass from its right end up to `at_m` (m, vectorized; clipped to the knots), for the
    density linear between the knots (`offset_m`, m, increasing; `mass_per_m`, relative mass per
    metre, >= 0) and zero beyond them: exact (a quadratic within each knot interval)."""
    xs, ms = offset_m, mass_per_m
    at = np.clip(np.asarray(at_m, dtype=float), xs[0], xs[-1])
    i = np.clip(np.searchsorted(xs, at, side="right") - 1, 0, xs.size - 2)
    slope = (ms[i + 1] - ms[i]) / (xs[i + 1] - xs[i])
    t = at - xs[i]
    before = np.concatenate(([0.0], np.cumsum(np.diff(xs) * (ms[:-1] + ms[1:]) / 2)))
    return before[i] + ms[i] * t + slope * t * t / 2
