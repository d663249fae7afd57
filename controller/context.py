"""What a controller may know each control period besides target and reading: its context.

A field run knows more than the two speeds: the ground speed, the prescription being applied, which
sections are on, the time, and the plant's nominal gain. A controller whose ``step`` takes a third
argument gets all of it as a `ControlContext` every period (a gain schedule on ground speed needs
it); a controller with the two-argument ``step`` gets what it always got (`takes_context` decides
once, when its loop is built, never per period)::

    def step(self, target_rpm, measured_rpm, context):   # context: ControlContext
        ...

The run hands the loop the drive's part per tick as a `ContextTrack` (``loop.run(targets,
context=track)``, `services.sim.core`): with a metering drive per section each loop gets its own
drive's ground speed and prescription (its section's, `services.sim.machines`); a loop run without
one (a step response, the look-ahead's response time, loop analysis) gives NaN speed and rate and no
sections.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError


@dataclass(frozen=True, slots=True)
class ControlContext:
    """One control period's context for n loops; the arrays are read-only.

    Attributes
    ----------
    target_rpm : ndarray, shape (n,)
        Target metering-shaft speed, clipped to ``[0, shaft_rpm_max]`` [rpm] (the ``target_rpm``
        argument).
    measured_rpm : ndarray, shape (n,)
        The speed sensor's reading: the shaft speed ``sensor_delay_s`` ago [rpm] (``measured_rpm``).
    speed_m_s : ndarray, shape (n,)
        Ground speed of each loop's metering drive as the machine senses it [m/s]: the sensed (radar
        or wheel) speed, or a section's own in a turn (a drive per section with turn compensation);
        NaN without a drive.
    prescribed_kg_ha : ndarray, shape (n,)
        The prescription where each loop's drive's product of this period will land [kg/ha] (a drive
        per section: its section's landing point); NaN without a drive.
    sections_on : ndarray of bool, shape (n, S)
        Which of the implement's S sections apply product (S = 0 without a drive).
    time_s : float
        Time at the start of this period since the loop started (or was reset) [s]: k T in period k.
    shaft_rpm_per_a : float
        The plant's nominal gain: steady-state shaft speed per ampere of valve current, no load
        [rpm/A] (`controller.PlantParams.shaft_rpm_per_a`; 250 rpm/A for the paper's plant).
    """

    target_rpm: np.ndarray
    measured_rpm: np.ndarray
    speed_m_s: np.ndarray
    prescribed_kg_ha: np.ndarray
    sections_on: np.ndarray
    time_s: float
    shaft_rpm_per_a: float


@dataclass(frozen=True)
class ContextTrack:
    """The drive's part of the context for K consecutive periods: one speed and prescription for all
    n loops, or each loop's own.

    Attributes
    ----------
    speed_m_s : ndarray, shape (K,) or (K, n)
        Sensed ground speed per period [m/s] (per period and loop: each loop's drive's).
    prescribed_kg_ha : ndarray, shape (K,) or (K, n)
        Prescription at the landing point per period [kg/ha] (per period and loop: each drive's).
    sections_on : ndarray of bool, shape (K, S)
        Each section's gate per period.
    """

    speed_m_s: np.ndarray
    prescribed_kg_ha: np.ndarray
    sections_on: np.ndarray

    def __post_init__(self):
        for name in ("speed_m_s", "prescribed_kg_ha", "sections_on"):
            value = np.asarray(getattr(self, name), dtype=bool if name == "sections_on" else float).view()
            value.flags.writeable = False     # a view: the caller's array stays as it is
            object.__setattr__(self, name, value)
        shapes = (self.speed_m_s.shape, self.prescribed_kg_ha.shape, self.sections_on.shape)
        k = shapes[0][0] if len(shapes[0]) in (1, 2) else -1
        if (shapes[1][:1] != (k,) or not 1 <= len(shapes[1]) <= 2 or len(shapes[2]) != 2
                or shapes[2][0] != k):
            raise ControllerError(f"context track must be speed (K,) or (K, n), rate (K,) or (K, n), "
                                  f"sections (K, S), got {', '.join(map(str, shapes))}")

    @classmethod
    def unknown(cls, periods: int) -> ContextTrack:
        """No drive: NaN speed and rate and no sections for `periods` periods."""
        nan = np.full(periods, np.nan)
        return cls(nan, nan, np.zeros((periods, 0), bool))

    def per_loop(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(speed (K, n), rate (K, n), sections (K, n, S)): read-only views (one value for all loops
        broadcast), so that row k is period k's (n,) and (n, S) arrays without a copy."""
        k = len(self.speed_m_s)
        return (_loops(self.speed_m_s, n, "speed_m_s"), _loops(self.prescribed_kg_ha, n, "prescribed_kg_ha"),
                np.broadcast_to(self.sections_on[:, None, :], (k, n, self.sections_on.shape[1])))


def _loops(values: np.ndarray, n: int, name: str) -> np.ndarray:
    """`values` (K,) for every one of n loops, or (K, n) each loop's, as (K, n)."""
    if values.ndim == 1:
        return np.broadcast_to(values[:, None], (len(values), n))
    if values.shape[1] != n:
        raise ControllerError(f"context track's {name} has {values.shape[1]} loops' values, the loop "
                              f"runs {n}")
    return values


def takes_context(step) -> bool:
    """Whether the bound method `step` takes the context as a third positional argument.

    Read once when a loop is built (`controller.PlantLoop`); a two-argument ``step`` (every
    controller written before the context existed, and the built-in kinds) is called as before.
    """
    try:
        inspect.signature(step).bind(None, None, None)
    except (TypeError, ValueError):   # two arguments only, or no signature to read (a builtin)
        return False
    return True
