"""Arithmetic that works on one loop's floats and on n loops' arrays alike, so a control law is written
once and runs fast in both cases.

A field run closes one loop (n = 1) for ~180,000 periods; a numpy call on a one-element array costs
about a microsecond, a float operation a few tens of nanoseconds. The built-in kinds therefore keep
their memory as Python floats when n = 1 and as arrays of shape (n,) otherwise, and write their law
with ``+ - * /``, comparisons, ``&``, ``|`` (which both support) and the helpers here. ``state()``
always gives arrays of shape (n,) (`as_array`), ``set_state`` takes them back (`from_array`).
"""

from __future__ import annotations

import numpy as np


def zeros(n: int):
    """0.0 for one loop, else ``np.zeros(n)``."""
    return 0.0 if n == 1 else np.zeros(n)


def full(n: int, value: float):
    """`value` for one loop, else ``np.full(n, value)``."""
    return float(value) if n == 1 else np.full(n, float(value))


def clip(x, lo, hi):
    """`x` within ``[lo, hi]`` (scalar bounds)."""
    if isinstance(x, np.ndarray):
        return np.minimum(np.maximum(x, lo), hi)
    return lo if x < lo else (hi if x > hi else x)


def where(cond, a, b):
    """`a` where `cond`, else `b` (``a if cond else b`` for one loop)."""
    if isinstance(cond, np.ndarray):
        return np.where(cond, a, b)
    return a if cond else b


def maximum(a, b):
    """Element-wise larger of `a` and `b`."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.maximum(a, b)
    return a if a > b else b


def absolute(x):
    """|x|."""
    return np.abs(x) if isinstance(x, np.ndarray) else abs(x)


def not_(cond):
    """Logical not of a condition (``~`` would turn a Python bool into an int)."""
    return np.logical_not(cond) if isinstance(cond, np.ndarray) else not cond


def any_(cond) -> bool:
    """Whether any loop's `cond` holds."""
    return bool(cond.any()) if isinstance(cond, np.ndarray) else bool(cond)


def all_(cond) -> bool:
    """Whether every loop's `cond` holds."""
    return bool(cond.all()) if isinstance(cond, np.ndarray) else bool(cond)


def as_array(x, n: int) -> np.ndarray:
    """A loop value (float or array) as a new float array of shape (n,), for ``state()``."""
    return np.array(x, dtype=float).reshape(n) if isinstance(x, np.ndarray) else np.full(n, float(x))


def from_array(a: np.ndarray, n: int):
    """The inverse of `as_array`: a float for one loop, else a copy of the array."""
    return float(a[0]) if n == 1 else np.array(a, dtype=float)
