"""What a loop of `controller` takes and gives, one definition for every kind (`controller.loop`'s
matrix loop, `controller.plant_loop`, the ideal meter): the targets checked and clipped, and what one
control period did (`StepOutput`).
"""

from __future__ import annotations

import numpy as np

from vrsim.common import ControllerError

__all__ = ["StepOutput", "clip_targets", "targets_matrix"]


class StepOutput:
    """What one control period did, per loop (all shape (n,)).

    Attributes
    ----------
    shaft_rpm : metering-shaft speed at the end of the period [rpm].
    shaft_rev : metering-shaft revolutions during the period (exact, from the angle state) [rev].
    current_a : valve current held during the period, after saturation [A].
    measured_rpm : the (delayed) speed-sensor reading the PID used this period [rpm].
    """

    __slots__ = ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm")

    def __init__(self, shaft_rpm, shaft_rev, current_a, measured_rpm):
        # a plain slotted class: a frozen dataclass costs ~1 us more per tick
        self.shaft_rpm = shaft_rpm
        self.shaft_rev = shaft_rev
        self.current_a = current_a
        self.measured_rpm = measured_rpm

    def __repr__(self):
        return (f"StepOutput(shaft_rpm={self.shaft_rpm}, shaft_rev={self.shaft_rev}, "
                f"current_a={self.current_a}, measured_rpm={self.measured_rpm})")


def clip_targets(target, n: int, rpm_max) -> np.ndarray:
    """Targets as shape (n,), clipped to [0, `rpm_max`]; NaN or a wrong shape is a `ControllerError`."""
    if isinstance(target, np.ndarray) and target.shape == (n,):
        r = target.astype(float, copy=False)
    else:
        try:
            r = np.broadcast_to(np.asarray(target, dtype=float), (n,))
        except (TypeError, ValueError):
            raise ControllerError(f"target_shaft_rpm must be a number or shape ({n},), "
                                  f"got {target!r}") from None
    r = np.minimum(np.maximum(r, 0.0), rpm_max)
    total = r.sum()
    if total != total:
        raise ControllerError(f"target_shaft_rpm must be numbers, got NaN in {target!r}")
    return r


def targets_matrix(targets_rpm, n: int) -> np.ndarray:
    """Targets of a run as shape (K, n) ((K,) is accepted for n = 1); `ControllerError` otherwise."""
    t = np.asarray(targets_rpm, dtype=float)
    if t.ndim == 1 and n == 1:
        t = t[:, None]
    if t.ndim != 2 or t.shape[1] != n:
        raise ControllerError(f"targets_rpm must have shape (K, {n}), got {np.shape(targets_rpm)}")
    return t
