"""Checks of the numbers in configurations and arguments, with messages that name the key and value.

One definition of "a finite number within bounds" for every package: a bool is not a number here
(``True`` is an int to Python, never a width to a user), and NaN or infinity never passes a bound.
"""

from __future__ import annotations

import math
import numbers

from vrsim.common.errors import VrsimError


def is_number(value) -> bool:
    """A finite real number: an int or float (or a numpy scalar of either), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def in_range(value, lo=None, hi=None, lo_open: bool = False) -> bool:
    """`value` is a finite number (`is_number`) within ``[lo, hi]`` (``(lo, hi]`` with `lo_open`)."""
    return is_number(value) and (lo is None or (value > lo if lo_open else value >= lo)) \
        and (hi is None or value <= hi)


def number_rule(lo=None, hi=None, lo_open: bool = False, unit: str = "") -> str:
    """The rule `check_number` enforces, in words: ``a number > 0``, ``a number in [0, 50]`` ..."""
    if lo is None and hi is None:
        rule = "a finite number"
    elif hi is None:
        rule = f"a number {'>' if lo_open else '>='} {lo:g}"
    elif lo is None:
        rule = f"a number <= {hi:g}"
    else:
        rule = f"a number in {'(' if lo_open else '['}{lo:g}, {hi:g}]"
    return f"{rule} {unit}" if unit else rule


def check_number(value, what: str, error: type[VrsimError] = VrsimError, *, lo=None, hi=None,
                 lo_open: bool = False, unit: str = "") -> float:
    """`value` as a float if it is a finite number within ``[lo, hi]`` (``(lo, hi]`` with `lo_open`).

    Parameters
    ----------
    value
        What the user gave.
    what : str
        Names it in the message, with its owner: ``"Implement: width_m"``.
    error : type
        The `VrsimError` subclass to raise (`MapError`, `VehicleError`, ...).
    lo, hi : float, optional
        Bounds; None: unbounded on that side.
    lo_open : bool
        Exclude `lo` itself (``> lo`` rather than ``>= lo``).
    unit : str
        Appended to the rule in the message (``"m"``, ``"s"``).

    Raises
    ------
    error
        ``"<what> must be <rule>, got <value!r>"``, e.g. ``Implement: width_m must be a number > 0,
        got -1.0``.
    """
    if not in_range(value, lo, hi, lo_open):
        raise error(f"{what} must be {number_rule(lo, hi, lo_open, unit)}, got {value!r}")
    return float(value)


def check_positive(value, what: str, error: type[VrsimError] = VrsimError, unit: str = "") -> float:
    """`check_number` with ``value > 0``: a width, a period, a cell size."""
    return check_number(value, what, error, lo=0.0, lo_open=True, unit=unit)
