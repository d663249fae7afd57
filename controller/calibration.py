"""The "valve cal" a rate-control terminal runs: hold the valve at fixed currents, read the shaft speed.

A terminal that does not know the hydraulics learns its valve's static curve by driving it open loop
at a series of currents and recording the steady speed its sensor reports (Raven's and others'
"valve calibration"; RateController's calibration page does the same for the meter). vrsim runs the
same test on the simulated plant, all points at once (one loop per point), and the feed-forward of
`ff_pi` inverts the recorded curve.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.interface import LoopInfo
from vrsim.controller.plant_loop import PlantLoop


@dataclass(frozen=True)
class ValveCal:
    """A valve calibration: the steady shaft speed read at each held current.

    Attributes
    ----------
    current_a : ndarray, shape (m,)
        Held currents, increasing [A].
    shaft_rpm : ndarray, shape (m,)
        Mean sensor reading over the end of each hold [rpm].
    """

    current_a: np.ndarray
    shaft_rpm: np.ndarray

    def current_for(self, shaft_rpm):
        """The current that holds `shaft_rpm` by the calibration, linearly interpolated [A]; targets
        beyond the calibrated speeds take the nearest end's current. An array or one float (for a
        float: `np.interp`'s arithmetic in Python, without its ~4 us call overhead)."""
        if isinstance(shaft_rpm, np.ndarray):
            return np.interp(shaft_rpm, self.shaft_rpm, self.current_a)
        xp, fp = self._points
        j = bisect.bisect_right(xp, shaft_rpm) - 1
        if j < 0:
            return fp[0]
        if j >= len(xp) - 1:
            return fp[-1]
        slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
        return slope * (shaft_rpm - xp[j]) + fp[j]

    @cached_property
    def _points(self) -> tuple[list, list]:
        return self.shaft_rpm.tolist(), self.current_a.tolist()


class _HeldCurrent:
    """An open-loop 'controller' that holds one current per loop (the calibration's drive)."""

    def __init__(self, current_a: np.ndarray):
        self.current_a = current_a

    def step(self, target_rpm, measured_rpm):
        return self.current_a

    def reset(self):
        pass

    def state(self):
        return {}

    def set_state(self, state):
        pass


def valve_calibration(info: LoopInfo, points: int = 11, hold_s: float = 3.0, average_s: float = 1.0,
                      load_torque_nm: float = 0.0) -> ValveCal:
    """Run a valve calibration on the plant of `info`.

    Parameters
    ----------
    info : LoopInfo
    points : int
        Number of currents, evenly spaced over ``[current_min_a, current_max_a]``.
    hold_s : float
        How long each current is held [s].
    average_s : float
        The sensor reading is averaged over the last `average_s` of each hold [s].
    load_torque_nm : float
        Load on the motor during the test [N m].
    """
    if isinstance(points, bool) or not isinstance(points, int) or points < 2:
        raise ControllerError(f"valve calibration points must be a whole number >= 2, got {points!r}")
    if not 0 < average_s <= hold_s:
        raise ControllerError(f"valve calibration average_s must be in (0, hold_s={hold_s!r}], "
                              f"got {average_s!r}")
    currents = np.linspace(info.current_min_a, info.current_max_a, points)
    loop = PlantLoop(info, _HeldCurrent(currents), n=points)
    periods = int(np.ceil(hold_s / info.control_period_s - 1e-9))
    averaged = max(1, int(round(average_s / info.control_period_s)))
    out = loop.run(np.zeros((periods, points)), load_torque_nm)    # held currents ignore the target
    speed = out.measured_rpm[-averaged:].mean(axis=0)
    if np.any(np.diff(speed) <= 0):
        raise ControllerError(f"valve calibration: the shaft speed does not rise with the current "
                              f"({np.round(speed, 3).tolist()} rpm at {np.round(currents, 3).tolist()} A)")
    return ValveCal(current_a=currents, shaft_rpm=speed)
