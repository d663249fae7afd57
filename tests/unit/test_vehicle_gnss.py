import numpy as np
import pytest

from vrsim.common.errors import VehicleError
from vrsim.vehicle import Gnss, GnssConfig


def _track(n=6000, dt=0.05):
    t = 3.0 + np.arange(n) * dt
    return t, 500000.0 + 2.5 * (t - 3.0), 5760000.0 + 10 * np.sin(t / 20)


@pytest.mark.parametrize("kind", ["rtk", "dgps", "autonomous", "perfect"])
@pytest.mark.parametrize("rate_hz, latency_s", [(10.0, 0.1), (5.0, 0.0), (1.0, 0.33), (20.0, 0.05)])
def test_per_tick_and_vectorized_give_identical_numbers(kind, rate_hz, latency_s):
    t, x, y = _track()
    cfg = GnssConfig(kind=kind, rate_hz=rate_hz, latency_s=latency_s)
    xm, ym = Gnss(cfg, seed=7).measure(t, x, y)
    g = Gnss(cfg, seed=7)
    per_tick = np.array([g.fix(a, b, c) for a, b, c in zip(t.tolist(), x.tolist(), y.tolist(), strict=True)])
    assert np.array_equal(per_tick[:, 0], xm) and np.array_equal(per_tick[:, 1], ym)


def test_seeded():
    t, x, y = _track()
    a = Gnss(GnssConfig("dgps"), seed=1).measure(t, x, y)
    b = Gnss(GnssConfig("dgps"), seed=1).measure(t, x, y)
    c = Gnss(GnssConfig("dgps"), seed=2).measure(t, x, y)
    assert np.array_equal(a[0], b[0]) and not np.array_equal(a[0], c[0])


@pytest.mark.parametrize("kind, sigma", [("rtk", 0.02), ("dgps", 0.3), ("autonomous", 1.5)])
def test_noise_magnitude_of_each_class(kind, sigma):
    # A standing receiver; a short correlation time so one track holds many independent errors.
    n = 200_000
    t = np.arange(n) * 0.1
    x = np.zeros(n)
    xm, ym = Gnss(GnssConfig(kind, rate_hz=10.0, latency_s=0.0, tau_s=1.0), seed=3).measure(t, x, x)
    assert np.std(xm) == pytest.approx(sigma, rel=0.05)
    assert np.std(ym) == pytest.approx(sigma, rel=0.05)
    assert abs(np.mean(xm)) < 0.05 * sigma


def test_errors_are_correlated_over_time():
    t = np.arange(100_000) * 0.1
    z = np.zeros_like(t)
    xm, _ = Gnss(GnssConfig("dgps", rate_hz=10.0, latency_s=0.0), seed=4).measure(t, z, z)
    lag1 = np.corrcoef(xm[:-1], xm[1:])[0, 1]
    assert lag1 == pytest.approx(np.exp(-0.1 / 60.0), abs=0.01)  # Gauss-Markov, tau 60 s


def test_sample_and_hold_and_latency():
    t = np.arange(100) * 0.05
    x = t * 2.0
    xm, _ = Gnss(GnssConfig("perfect", rate_hz=5.0, latency_s=0.3), seed=1).measure(t, x, x)
    # Fix j samples t = 0.2 j and is output from 0.2 j + 0.3 on; fix 0 before that.
    expect = 2.0 * 0.2 * np.maximum(np.floor((t - 0.3) * 5.0 + 1e-9), 0)
    assert np.allclose(xm, expect, atol=1e-9)
    assert len(np.unique(xm[:20])) == 4


def test_fix_between_ticks_is_interpolated():
    t = np.array([0.0, 0.15, 0.3, 0.45])  # ticks slower than the 10 Hz fixes
    x = np.array([0.0, 1.5, 3.0, 4.5])
    xm, _ = Gnss(GnssConfig("perfect", rate_hz=10.0, latency_s=0.0)).measure(t, x, x)
    assert np.allclose(xm, [0.0, 1.0, 3.0, 4.0])


@pytest.mark.parametrize("kwargs, match", [
    (dict(kind="galileo"), "kind must be one of"),
    (dict(rate_hz=0), "rate_hz"),
    (dict(latency_s=-0.1), "latency_s"),
    (dict(sigma_m=-1.0), "sigma_m"),
    (dict(tau_s=0.0), "tau_s"),
])
def test_bad_config(kwargs, match):
    with pytest.raises(VehicleError, match=match):
        GnssConfig(**kwargs)


def test_bad_tracks():
    g = Gnss(GnssConfig(), seed=1)
    with pytest.raises(VehicleError, match="strictly increasing"):
        g.measure([0.0, 0.0], [1.0, 2.0], [1.0, 2.0])
    with pytest.raises(VehicleError, match="one length"):
        g.measure([0.0, 1.0], [1.0], [1.0, 2.0])
    g.fix(1.0, 0.0, 0.0)
    with pytest.raises(VehicleError, match="must increase"):
        g.fix(1.0, 0.0, 0.0)
    with pytest.raises(VehicleError, match="seed"):
        Gnss(GnssConfig(), seed=-1)


def test_sensors_refuse_ragged_or_unordered_tracks():
    from vrsim.vehicle import SpeedSensor

    with pytest.raises(VehicleError, match=r"Gnss.measure: time_s, x_m, y_m must be 1-D of one length"):
        Gnss(GnssConfig()).measure([0.0, 1.0], [0.0], [0.0, 1.0])
    with pytest.raises(VehicleError, match="SpeedSensor.measure: time_s must be strictly increasing"):
        SpeedSensor().measure([1.0, 0.0], [1.0, 1.0])


@pytest.mark.parametrize("kind", ["rtk", "autonomous"])
@pytest.mark.parametrize("rate_hz, latency_s", [(10.0, 0.1), (1.0, 0.33), (20.0, 0.05)])
@pytest.mark.parametrize("cuts", [(1,), (7, 2000, 2001, 4500), (20, 40, 5999)])
def test_a_track_measured_in_parts_equals_the_track_measured_whole(kind, rate_hz, latency_s, cuts):
    from vrsim.vehicle import SpeedSensor, SpeedSensorConfig

    t, x, y = _track()
    v = 2.5 + 0.3 * np.sin(t)
    cfg = GnssConfig(kind=kind, rate_hz=rate_hz, latency_s=latency_s)
    whole = Gnss(cfg, seed=3).measure(t, x, y)
    speed_cfg = SpeedSensorConfig("radar", rate_hz=rate_hz)
    whole_v = SpeedSensor(speed_cfg, seed=3).measure(t, v)
    g, s = Gnss(cfg, seed=3), SpeedSensor(speed_cfg, seed=3)
    bounds = [0, *cuts, len(t)]
    spans = list(zip(bounds[:-1], bounds[1:], strict=True))
    parts = [(g.measure if a == 0 else g.measure_next)(t[a:b], x[a:b], y[a:b]) for a, b in spans]
    parts_v = [(s.measure if a == 0 else s.measure_next)(t[a:b], v[a:b]) for a, b in spans]
    assert np.array_equal(np.concatenate([p[0] for p in parts]), whole[0])
    assert np.array_equal(np.concatenate([p[1] for p in parts]), whole[1])
    assert np.array_equal(np.concatenate(parts_v), whole_v)


def test_a_part_must_come_after_the_ticks_measured():
    t, x, y = _track(100)
    g = Gnss(GnssConfig(), seed=1)
    g.measure(t[:50], x[:50], y[:50])
    with pytest.raises(VehicleError, match="measure_next: time_s must increase"):
        g.measure_next(t[49:], x[49:], y[49:])
