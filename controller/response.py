"""How long a loop takes to follow a target step: the controller's own lag, for the look-ahead.

Product is metered in proportion to the shaft's revolutions, so the lag that matters is that of the
shaft speed averaged over each control period (exact, from the revolutions; free of the motor's
1 ms ringing). `response_time` settles n = 2 loops of any kind at a low and a high target, steps one
up and one down, and measures on that per-period mean speed, as progress ``p(t) = (y - y0)/(y1 - y0)``
from the settled level before the step to the level the loop reaches (the mean of the record's last
second; a deadband's offset is not lag):

* ``t50_s``, ``t63_s``, ``t90_s``: first time p reaches 0.5, 0.63, 0.9, each period's mean placed at
  the period's midpoint and interpolated linearly from the step (at t = 0, p = 0 at -T/2);
* ``mean_lag_s``: ``integral of (1 - p) dt`` from the step, the centroid of the transition: the time by
  which the metered product lags an ideal meter's on average (exactly the delay for a pure delay,
  the time constant for a first-order lag, 0 for the ideal meter).

``look_ahead_s`` (the mean of the up and down steps' mean lags) is what the "auto" look-ahead adds
to the delivery delay.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.config import ControllerConfig
from vrsim.controller.factory import build_loop
from vrsim.controller.plant import PlantParams

FRACTIONS = (0.5, 0.63, 0.9)


@dataclass(frozen=True)
class StepTiming:
    """Timing of one step (see the module docstring) [s]; NaN where p never reached the fraction."""

    t50_s: float
    t63_s: float
    t90_s: float
    mean_lag_s: float


@dataclass(frozen=True)
class ResponseTime:
    """Response of a loop to a step up (low -> high target) and down (high -> low)."""

    low_rpm: float
    high_rpm: float
    up: StepTiming
    down: StepTiming

    @property
    def look_ahead_s(self) -> float:
        """Mean of the up and down steps' mean lags [s]: the controller's share of the look-ahead."""
        return 0.5 * (self.up.mean_lag_s + self.down.mean_lag_s)

    def to_dict(self) -> dict:
        """Plain data (NaN stays NaN: the caller's JSON encoder decides)."""
        return {**asdict(self), "look_ahead_s": self.look_ahead_s}


def _timing(mean_rpm: np.ndarray, before_rpm: float, control_period_s: float) -> StepTiming:
    """Timing of one loop's per-period mean speeds after the step (`mean_rpm`, from the step on)."""
    t = control_period_s
    final = mean_rpm[-max(1, int(round(1.0 / t))):].mean()
    if abs(final - before_rpm) < 1e-9 * max(1.0, abs(final)):
        raise ControllerError(f"the loop did not move after the step (stayed at {final:.4g} rpm)")
    p = np.concatenate([[0.0], (mean_rpm - before_rpm) / (final - before_rpm)])
    times = (np.arange(len(p)) - 0.5) * t
    crossing = []
    for f in FRACTIONS:
        above = np.nonzero(p >= f)[0]
        if len(above) == 0:
            crossing.append(float("nan"))
            continue
        i = above[0]
        crossing.append(float(times[i - 1] + (f - p[i - 1]) / (p[i] - p[i - 1]) * t))
    return StepTiming(*crossing, mean_lag_s=float(np.sum(1.0 - p[1:]) * t))


def response_time(plant: PlantParams, cfg: ControllerConfig, control_period_s: float = 0.05,
                  plant_step_s: float = 0.001, low_rpm: float | None = None, high_rpm: float | None = None,
                  settle_s: float = 10.0, record_s: float = 10.0) -> ResponseTime:
    """Measure the response time of `cfg`'s loop on `plant` (see the module docstring).

    Parameters
    ----------
    low_rpm, high_rpm : float, optional
        The two targets [rpm]; default 30 % and 60 % of the plant's ``shaft_rpm_max``.
    settle_s : float
        Time at the first target before the step [s].
    record_s : float
        Time recorded after the step [s]; the last second gives the level reached.
    """
    low = 0.3 * plant.shaft_rpm_max if low_rpm is None else float(low_rpm)
    high = 0.6 * plant.shaft_rpm_max if high_rpm is None else float(high_rpm)
    if not 0.0 <= low < high <= plant.shaft_rpm_max:
        raise ControllerError(f"response time needs 0 <= low_rpm < high_rpm <= shaft_rpm_max "
                              f"({plant.shaft_rpm_max:g}), got {low!r}, {high!r}")
    if not (settle_s > 0 and record_s >= 1.0):
        raise ControllerError(f"response time needs settle_s > 0 and record_s >= 1, got {settle_s!r}, "
                              f"{record_s!r}")
    loop = build_loop(plant, cfg, control_period_s, plant_step_s, n=2)
    before = int(np.ceil(settle_s / control_period_s))
    after = int(np.ceil(record_s / control_period_s))
    targets = np.vstack([np.tile([low, high], (before, 1)), np.tile([high, low], (after, 1))])
    mean_rpm = loop.run(targets).shaft_rev * 60.0 / control_period_s
    settled = mean_rpm[before - max(1, int(round(1.0 / control_period_s))):before].mean(axis=0)
    up, down = (_timing(mean_rpm[before:, i], settled[i], control_period_s) for i in (0, 1))
    return ResponseTime(low_rpm=low, high_rpm=high, up=up, down=down)
