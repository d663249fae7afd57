"""The look-ahead's motion model (services.sim.sections.motion): the causal acceleration and yaw-rate
estimate, and the pose predicted along the arc with each section at its own ground speed."""

import numpy as np
import pytest

from vrsim.services.sim.sections.motion import TREND_WINDOW_S, Motion, MotionTrend

PERIOD_S = 0.05


def _motion(v, a=0.0, w=0.0, heading=0.0):
    one = np.ones(1)
    return Motion(0 * one, 0 * one, heading * one, v * one, a * one, w * one)


def test_straight_at_constant_acceleration_travels_v_t_plus_half_a_t_squared():
    x, y, cos, sin = _motion(1.2, a=0.8).ahead(1.8)
    assert x[0] == pytest.approx(1.2 * 1.8 + 0.4 * 1.8 ** 2) and y[0] == pytest.approx(0.0)
    assert (cos[0], sin[0]) == pytest.approx((1.0, 0.0))


def test_braking_stops_where_the_speed_reaches_zero():
    distance, moving = _motion(2.0, a=-1.5).travel(3.0)
    assert distance[0] == pytest.approx(2.0 ** 2 / 3.0) and moving[0] == pytest.approx(2.0 / 1.5)


def test_a_turn_at_constant_speed_stays_on_the_circle_and_each_section_at_its_own_speed():
    v, radius, lead = 2.0, 10.0, 1.5
    w = v / radius                                   # counter-clockwise: the centre of the turn is left
    x, y, cos, sin = _motion(v, w=w, heading=0.3).ahead(lead)
    centre = np.array([-np.sin(0.3), np.cos(0.3)]) * radius
    assert np.hypot(x[0] - centre[0], y[0] - centre[1]) == pytest.approx(radius)
    assert np.arctan2(sin[0], cos[0]) == pytest.approx(0.3 + w * lead)
    # A section 4 m left (inside) has moved along its own circle by (v - w * 4) * lead.
    sx, sy = x[0] - sin[0] * 4.0, y[0] + cos[0] * 4.0
    chord = np.hypot(sx - (-np.sin(0.3) * 4.0), sy - np.cos(0.3) * 4.0)
    arc = 2 * (radius - 4.0) * np.arcsin(chord / (2 * (radius - 4.0)))
    assert arc == pytest.approx((v - w * 4.0) * lead)


def test_trend_measures_acceleration_and_yaw_rate_after_its_window():
    t = np.arange(200) * PERIOD_S
    v = 1.0 + 0.5 * t
    heading = np.pi - 0.05 + 0.2 * t                 # crosses +-pi: the change is wrapped
    m = MotionTrend(PERIOD_S).step(t * 0, t * 0, np.angle(np.exp(1j * heading)), v)
    full = t >= TREND_WINDOW_S
    np.testing.assert_allclose(m.accel_m_s2[full], 0.5, rtol=1e-9)
    np.testing.assert_allclose(m.yaw_rate_rad_s[full], 0.2, rtol=1e-9)
    assert m.accel_m_s2[0] == 0.0 and 0 < m.accel_m_s2[5] < 0.5   # nothing known before the first tick


def test_trend_in_batches_equals_one_step_also_after_json():
    rng = np.random.default_rng(4)
    n = 500
    v, h = 2.0 + rng.normal(0, 0.05, n), np.cumsum(rng.normal(0, 0.02, n))
    whole = MotionTrend(PERIOD_S).step(np.zeros(n), np.zeros(n), h, v)
    trend, parts = MotionTrend(PERIOD_S), []
    for a, b in ((0, 0), (0, 3), (3, 4), (4, 130), (130, 500)):
        again = MotionTrend(PERIOD_S)
        again.set_state(trend.state())
        trend = again
        parts.append(trend.step(np.zeros(b - a), np.zeros(b - a), h[a:b], v[a:b]))
    joined = Motion.join(parts)
    for field in Motion.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(joined, field), getattr(whole, field))
