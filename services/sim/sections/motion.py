"""Where the implement will be: the look-ahead predicted from the sensed speed, acceleration and yaw rate.

The terminal knows the pose (position, heading) and the ground speed at each tick. From their recent
change it estimates the tractor's acceleration and yaw rate (`MotionTrend`: causal, over the last
`TREND_WINDOW_S`, as a real controller would) and predicts the pose a lead time t ahead
(`Motion.ahead`): the centre travels ``d = v t + a t^2 / 2`` (until it would stop) along an arc whose
heading turns by ``w t``. A section at lateral offset o, placed at its offset across the predicted
pose, has then travelled ``d - w t o``: its own ground speed is the centre's minus the yaw rate times
its offset (left positive, counter-clockwise yaw positive), so the inner sections of a turn look less
far ahead than the outer ones.

At constant speed on a straight line the prediction is ``v t`` straight ahead; where the tractor
speeds up out of a headland turn, the sections look as far ahead as it will really travel. Where the
acceleration or the yaw rate changes within the lead (the end of a turn, of a speed-up or slow-down),
the extrapolation errs, and the mean over the window lags by half of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TREND_WINDOW_S = 0.5  # acceleration and yaw rate: the mean change over this long before each tick


@dataclass(frozen=True)
class Motion:
    """The terminal's view of the implement's motion per tick; arrays of shape (m,).

    Attributes
    ----------
    x_m, y_m : ndarray
        Position (field CRS, m).
    heading_rad : ndarray
        Heading, math convention.
    speed_m_s : ndarray
        Sensed ground speed, m/s.
    accel_m_s2 : ndarray
        Estimated acceleration along the path, m/s^2 (`MotionTrend`).
    yaw_rate_rad_s : ndarray
        Estimated yaw rate, rad/s, counter-clockwise positive (`MotionTrend`).
    """

    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    speed_m_s: np.ndarray
    accel_m_s2: np.ndarray
    yaw_rate_rad_s: np.ndarray

    def travel(self, lead_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Distance the centre travels in the next `lead_s` s [m] and the time it moves [s]: at the
        estimated acceleration, up to where it would stop."""
        v, a = self.speed_m_s, self.accel_m_s2
        # Decelerating to a stop within the lead: it travels v^2 / 2|a| in v/|a| s, then stands.
        stops = a * lead_s < -v
        moving_s = np.where(stops, np.divide(v, -a, out=np.zeros_like(v), where=stops), lead_s)
        distance_m = np.maximum(v * moving_s + 0.5 * a * moving_s * moving_s, 0.0)
        return distance_m, moving_s

    def ground_speed_m_s(self, offsets_m) -> np.ndarray:
        """The ground speed along the heading of points at lateral offsets `offsets_m` (m, left
        positive, shape (k,)) across the implement: ``v - yaw_rate * offset``, m/s (m, k); negative
        where the point moves backwards (the inner end of a turn tighter than its offset)."""
        return self.speed_m_s[:, None] - self.yaw_rate_rad_s[:, None] * np.asarray(offsets_m, float)

    def ahead(self, lead_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The pose `lead_s` s ahead along the predicted arc: (x_m, y_m, cos, sin) of its heading.

        The chord of an arc of length d turning by dh is ``d sinc(dh / 2)`` long, along the heading
        turned by dh / 2.
        """
        return self.pose_after(*self.travel(lead_s))

    def pose_after(self, distance_m: np.ndarray, moving_s: np.ndarray):
        """`ahead`'s pose from what `travel` gives for its lead: the centre's distance [m] and the time it
        moves [s] (for a caller that needs the distance too)."""
        turn = self.yaw_rate_rad_s * moving_s
        chord_m = distance_m * np.sinc(turn / (2 * np.pi))   # np.sinc(x) = sin(pi x) / (pi x)
        middle = self.heading_rad + 0.5 * turn
        end = self.heading_rad + turn
        return (self.x_m + chord_m * np.cos(middle), self.y_m + chord_m * np.sin(middle),
                np.cos(end), np.sin(end))

    def part(self, part) -> Motion:
        """The ticks `part` (a slice or indices)."""
        return Motion(*(getattr(self, f)[part] for f in Motion.__dataclass_fields__))

    @classmethod
    def join(cls, motions: list[Motion]) -> Motion:
        """Consecutive batches as one."""
        return cls(*(np.concatenate([getattr(m, f) for m in motions]) for f in cls.__dataclass_fields__))


class MotionTrend:
    """Acceleration and yaw rate per tick from the sensed speed and heading, causal, across `step` calls.

    Each tick's estimate is the mean change per second over the last `TREND_WINDOW_S` (k ticks):
    ``(v[t] - v[t-k]) / (k T)``, the heading's change wrapped to (-pi, pi]. The mean over a window
    smooths the speed sensor's noise and its sample-and-hold steps; it lags by half the window. Before
    the first tick the speed and heading are taken as the first tick's (no motion change), so a track
    stepped in batches of any size gives the estimates of one step over the whole track.

    Parameters
    ----------
    period_s : float
        Control period (one tick), s.
    """

    def __init__(self, period_s: float):
        self.period_s = float(period_s)
        self.window = max(1, round(TREND_WINDOW_S / period_s))
        self.speeds = np.zeros(0)     # the last `window` ticks' speeds [m/s] (empty before the first)
        self.headings = np.zeros(0)   # ... and headings [rad]

    def step(self, x_m, y_m, heading_rad, speed_m_s) -> Motion:
        """The motion of the next m ticks (arrays of shape (m,): position m, heading rad, speed m/s)."""
        x, y, h, v = (np.asarray(a, float) for a in (x_m, y_m, heading_rad, speed_m_s))
        if not v.size:
            return Motion(x, y, h, v, np.zeros(0), np.zeros(0))
        k = self.window
        if not self.speeds.size:
            self.speeds, self.headings = np.full(k, v[0]), np.full(k, h[0])
        speeds, headings = np.concatenate((self.speeds, v)), np.concatenate((self.headings, h))
        span_s = k * self.period_s
        accel = (speeds[k:] - speeds[:-k]) / span_s
        turned = np.remainder(headings[k:] - headings[:-k] + np.pi, 2 * np.pi) - np.pi
        self.speeds, self.headings = speeds[-k:], headings[-k:]
        return Motion(x, y, h, v, accel, turned / span_s)

    def state(self) -> dict:
        """What the trend carries to the next `step`, as plain data (JSON-safe)."""
        return {"speeds": self.speeds.tolist(), "headings": self.headings.tolist()}

    def set_state(self, state: dict) -> None:
        """Continue from what `state` returned."""
        self.speeds = np.asarray(state["speeds"], float)
        self.headings = np.asarray(state["headings"], float)
