"""The sprayer's boom (vehicle/sprayer.py): the ISO nozzle law, the speed range the nozzles' pressure
range allows, the nozzle that would cover a rate range, the flow meter's error, PWM turn compensation
and bad keys."""

import dataclasses

import numpy as np
import pytest

from vrsim.common.errors import VehicleError
from vrsim.vehicle.sprayer import (
    NOZZLE_FLOW_L_MIN,
    FlowMeter,
    SprayerSpec,
    applied_rate_l_ha,
    boom_flow_l_min,
    density_flow_factor,
    nozzle_flow_l_min,
    nozzle_pressure_bar,
    nozzle_speeds_m_s,
    pwm_duty_pct,
    pwm_open_fraction,
    pwm_phases,
)


# --- the nozzle law ---------------------------------------------------------------------------------------
def test_nozzle_flow_follows_iso_table():
    # ISO 10625 nominal flows at 3 bar, and catalogue values (TeeJet XR) at other pressures
    assert nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["02"], 3.0) == pytest.approx(0.8)
    assert nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["02"], 2.0) == pytest.approx(0.653, abs=5e-4)
    assert nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["04"], 5.0) == pytest.approx(2.07, abs=0.01)
    assert nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["015"], 4.0) == pytest.approx(0.69, abs=0.005)
    sizes = ["01", "015", "02", "025", "03", "04", "05", "06", "08"]
    assert [NOZZLE_FLOW_L_MIN[s] for s in sizes] == [0.4, 0.6, 0.8, 1.0, 1.2, 1.6, 2.0, 2.4, 3.2]


def test_nozzle_pressure_inverts_the_law():
    p = np.array([1.5, 2.0, 3.0, 5.0])
    assert nozzle_pressure_bar(0.8, nozzle_flow_l_min(0.8, p)) == pytest.approx(p)


def test_a_denser_liquid_passes_sqrt_one_over_its_specific_gravity_of_the_water_rating():
    # An orifice, q = C A sqrt(2 dp / rho): UAN 28 % at 1.28 kg/L, TeeJet's conversion factor 0.88
    assert density_flow_factor(1.28) == pytest.approx(0.88, abs=0.005)
    assert density_flow_factor(1.28) == pytest.approx(np.sqrt(1 / 1.28), rel=1e-15)
    assert nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["04"], 3.0, 1.28) == pytest.approx(1.414, abs=5e-4)
    assert nozzle_flow_l_min(1.6, 5.0, 1.28) == pytest.approx(1.6 * np.sqrt(5 / 3) / np.sqrt(1.28))
    # the same flow needs SG times the pressure
    assert nozzle_pressure_bar(1.6, 1.6, 1.28) == pytest.approx(3.0 * 1.28)
    p = np.array([1.0, 2.0, 5.0])
    assert nozzle_pressure_bar(1.6, nozzle_flow_l_min(1.6, p, 1.28), 1.28) == pytest.approx(p)
    # water, stated or not, is the rating itself, bit for bit
    assert density_flow_factor(None) == density_flow_factor(1.0) == 1.0
    q = nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["06"], np.linspace(1.0, 8.0, 15))
    assert np.array_equal(nozzle_flow_l_min(NOZZLE_FLOW_L_MIN["06"], np.linspace(1.0, 8.0, 15), 1.0), q)
    with pytest.raises(VehicleError, match="density_kg_l"):
        density_flow_factor(0.0)


def test_the_pressure_range_speeds_and_advice_follow_the_liquids_flows():
    f = np.sqrt(1 / 1.28)
    spec = SprayerSpec(nozzle="04", pressure_range_bar=(1.0, 5.0))
    water = spec.nozzle_flow_range_l_min()
    assert spec.nozzle_flow_range_l_min(density_kg_l=1.28) == pytest.approx((water[0] * f, water[1] * f))
    assert spec.nozzle_flow_range_l_min(density_kg_l=None) == water
    assert spec.rated_flow_l_min(1.28) == pytest.approx(1.6 * f) and spec.rated_flow_l_min() == 1.6
    lo, hi = spec.speed_range_m_s(160.0, 220.0)
    assert spec.speed_range_m_s(160.0, 220.0, density_kg_l=1.28) == pytest.approx((lo * f, hi * f))
    assert spec.check_rates(160.0, 220.0, 1.28) == pytest.approx((lo * f, hi * f))
    # 160-220 L/ha at 2.5 m/s: 1.2-1.65 L/min a nozzle; an 04 gives 0.92-2.07 of water, 0.82-1.83 of UAN,
    # which a 05 (1.02-2.28) centres better
    assert spec.suggest_nozzle(160.0, 220.0, 2.5) == "04"
    assert spec.suggest_nozzle(160.0, 220.0, 2.5, 1.28) == "05"
    with pytest.raises(VehicleError, match=r"nozzle '04' \(0\.816-1\.83 L/min per nozzle\)"):
        spec.check_rates(50.0, 400.0, 1.28)
    pwm = SprayerSpec(nozzle="02", control="pwm", duty_range_pct=(10.0, 100.0), pwm_pressure_bar=3.0)
    assert pwm.nozzle_flow_range_l_min(density_kg_l=1.28) == pytest.approx((0.08 * f, 0.8 * f))


def test_boom_flow_and_its_inverse():
    # 2.5 m/s x 12 m = 30 m^2/s = 0.003 ha/s: 0.6 L/s of 200 L/ha, 36 L/min
    assert boom_flow_l_min(200.0, 2.5, 12.0) == pytest.approx(36.0)
    # the catalogue formula: L/min per nozzle = L/ha x km/h x spacing cm / 60 000
    assert boom_flow_l_min(160.0, 9.0 / 3.6, 0.5) == pytest.approx(160.0 * 9.0 * 50.0 / 60_000)
    assert applied_rate_l_ha(36.0, 2.5, 12.0) == pytest.approx(200.0)
    assert applied_rate_l_ha(36.0, -2.5, 12.0) == pytest.approx(200.0)    # moving backwards in a turn
    assert np.isnan(applied_rate_l_ha(np.array([1.0]), np.array([0.0]), 0.5)[0])


# --- the machine limit ------------------------------------------------------------------------------------
def test_speed_range_puts_the_nozzles_at_their_pressure_limits():
    spec = SprayerSpec(nozzle="02", nozzle_spacing_m=0.5, pressure_range_bar=(1.5, 5.0))
    lo, hi = spec.speed_range_m_s(200.0)
    # v = (10 000 / 60) q / (200 * 0.5) at q = 0.8 sqrt(1.5 / 3) and 0.8 sqrt(5 / 3)
    per_q = 10_000 / 60 / 100
    assert (lo, hi) == pytest.approx((per_q * 0.8 * np.sqrt(0.5), per_q * 0.8 * np.sqrt(5 / 3)))
    per_nozzle = boom_flow_l_min(200.0, np.array([lo, hi]), 0.5)
    assert nozzle_pressure_bar(0.8, per_nozzle) == pytest.approx([1.5, 5.0])
    lo2, hi2 = spec.speed_range_m_s(150.0, 250.0)                   # a range: the tighter ends
    assert lo2 == pytest.approx(spec.speed_range_m_s(150.0)[0])
    assert hi2 == pytest.approx(spec.speed_range_m_s(250.0)[1])


def test_rates_wider_than_the_nozzle_have_no_speed_and_say_so():
    spec = SprayerSpec(nozzle="02")
    assert spec.speed_range_m_s(50.0, 400.0) is None        # 8x the rate, the nozzle gives 1.83x
    with pytest.raises(VehicleError) as err:
        spec.check_rates(50.0, 400.0)
    msg = str(err.value)
    assert "\n" not in msg and "nozzle '02'" in msg and "50-400 L/ha" in msg
    assert spec.check_rates(150.0, 250.0) == spec.speed_range_m_s(150.0, 250.0)


def test_pwm_widens_the_range_to_the_duty_cycle():
    flow = SprayerSpec(nozzle="02")
    pwm = SprayerSpec(nozzle="02", control="pwm", duty_range_pct=(10.0, 100.0), pwm_pressure_bar=3.0)
    assert pwm.nozzle_flow_range_l_min() == pytest.approx((0.08, 0.8))
    assert pwm.speed_range_m_s(50.0, 400.0) is not None and flow.speed_range_m_s(50.0, 400.0) is None


def test_suggested_nozzle_covers_the_rates_at_the_working_speed():
    spec = SprayerSpec(nozzle="04")
    # 200-300 L/ha at 3 m/s every 0.5 m needs 1.8-2.7 L/min: only the 06 (1.70-3.10 L/min) covers it
    assert spec.suggest_nozzle(200.0, 300.0, 3.0) == "06"
    fitted = dataclasses.replace(spec, nozzle="06")
    lo, hi = fitted.speed_range_m_s(200.0, 300.0)
    assert lo <= 3.0 <= hi
    assert spec.suggest_nozzle(20.0, 800.0, 3.0) is None
    # a narrow range: the size with the needed flow nearest the middle of its range (log terms)
    need = boom_flow_l_min(250.0, 2.5, 0.5)                           # 1.875 L/min
    size = spec.suggest_nozzle(250.0, 250.0, 2.5)
    p = nozzle_pressure_bar(NOZZLE_FLOW_L_MIN[size], need)
    assert 1.5 <= p <= 5.0 and abs(np.log(p / np.sqrt(1.5 * 5.0))) < np.log(1.5)


def test_nozzles_across_the_boom():
    spec = SprayerSpec(nozzle_spacing_m=0.5)
    assert spec.nozzle_count(12.0) == 24
    off = spec.nozzle_offsets_m(12.0)
    assert off[0] == pytest.approx(-5.75) and off[-1] == pytest.approx(5.75)
    assert np.diff(off) == pytest.approx(0.5)
    with pytest.raises(VehicleError, match="nozzle_spacing_m 0.7"):
        SprayerSpec(nozzle_spacing_m=0.7).nozzle_count(12.0)


# --- the flow meter ---------------------------------------------------------------------------------------
def test_flow_meter_reads_its_calibration_error():
    meter = SprayerSpec(flow_meter_pulses_per_l=600.0, flow_meter_error_pct=5.0).meter
    assert meter.pulses(10.0) == 6300                      # its true constant is 630 pulses/L
    assert meter.metered_l(10.0) == pytest.approx(10.5)
    # a controller holding the meter's 10 L/min on target lets 10 / 1.05 L/min land
    assert meter.true_l(10.0) == pytest.approx(10.0 / 1.05)
    steps = np.cumsum(np.full(100, 0.001))                 # 1 mL at a time: whole pulses only
    counted = meter.metered_l(steps)
    assert np.all(np.diff(counted) >= 0) and counted[-1] == pytest.approx(63 / 600)
    assert FlowMeter().metered_l(1.0) == pytest.approx(1.0)


# --- PWM --------------------------------------------------------------------------------------------------
def _turn(compensate: bool, radius_m=20.0, speed_m_s=2.5, rate_l_ha=150.0, ticks=400):
    """Applied rate per nozzle in a steady left turn of the boom's centre at `radius_m`: from the mean
    duty (K, N), from the pulse trains (N,), and the nozzles' offsets."""
    # an 04 open at 3 bar gives 1.6 L/min: 150 L/ha needs 50 % duty inside (14.25 m), 90 % outside (25.75 m)
    spec = SprayerSpec(nozzle="04", control="pwm", pwm_pressure_bar=3.0, duty_range_pct=(10.0, 100.0))
    offsets = spec.nozzle_offsets_m(12.0)
    speed = np.full(ticks, speed_m_s)
    yaw = speed / radius_m                                 # counter-clockwise: the left nozzles are inside
    v_nozzle = nozzle_speeds_m_s(speed, yaw, offsets)
    q_open = float(nozzle_flow_l_min(spec.q_ref_l_min, spec.pwm_pressure_bar))
    used = v_nozzle if compensate else np.broadcast_to(speed[:, None], v_nozzle.shape)
    duty = pwm_duty_pct(np.full(ticks, rate_l_ha), used, spec.nozzle_spacing_m, q_open, spec.duty_range_pct)
    mean_rate = applied_rate_l_ha(duty / 100 * q_open, v_nozzle, spec.nozzle_spacing_m)
    tick_s = 0.05
    opened = pwm_open_fraction(duty, np.arange(ticks) * tick_s, tick_s, spec.pwm_hz, pwm_phases(len(offsets)))
    pulsed_rate = applied_rate_l_ha(opened.mean(axis=0) * q_open, v_nozzle[0], spec.nozzle_spacing_m)
    return mean_rate, pulsed_rate, offsets


def test_turn_compensation_evens_the_rate_across_the_boom():
    mean_rate, pulsed_rate, offsets = _turn(compensate=True)
    inside_to_outside = mean_rate[0, 0] / mean_rate[0, -1]
    assert inside_to_outside == pytest.approx(1.0, abs=0.05)
    assert mean_rate[0] == pytest.approx(150.0)
    assert pulsed_rate[0] / pulsed_rate[-1] == pytest.approx(1.0, abs=0.05)   # the pulse trains agree


def test_without_compensation_the_rate_follows_the_geometry():
    mean_rate, pulsed_rate, offsets = _turn(compensate=False)
    geometric = (20.0 + offsets[-1]) / (20.0 + offsets[0])          # outside radius / inside radius
    assert geometric == pytest.approx(25.75 / 14.25)
    assert mean_rate[0, 0] / mean_rate[0, -1] == pytest.approx(geometric)
    assert pulsed_rate[0] / pulsed_rate[-1] == pytest.approx(geometric, rel=0.02)


def test_duty_is_clipped_to_its_range_and_zero_when_off():
    v = np.full((3, 2), 2.5)
    duty = pwm_duty_pct(np.array([1.0, 0.0, 5000.0]), v, 0.5, 0.8, (10.0, 100.0))
    assert duty[0] == pytest.approx([10.0, 10.0])          # 1 L/ha needs 0.3 %: the limit over-applies
    assert duty[1] == pytest.approx([0.0, 0.0])
    assert duty[2] == pytest.approx([100.0, 100.0])


def test_pulse_train_averages_to_the_duty():
    ticks, tick_s = 600, 0.05
    duty = np.full((ticks, 2), 37.0)
    opened = pwm_open_fraction(duty, np.arange(ticks) * tick_s, tick_s, 15.0, pwm_phases(2))
    assert np.all((opened >= 0) & (opened <= 1))
    assert opened.mean(axis=0) == pytest.approx([0.37, 0.37], abs=1e-3)
    assert opened[:, 0].std() > 0.01                        # a 50 ms tick holds 0.75 of a 15 Hz pulse
    assert pwm_phases(4) == pytest.approx([0.0, 0.5, 0.0, 0.5])


# --- bad keys ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, value", [
    ("nozzle", "07"), ("nozzle", 2), ("nozzle_spacing_m", 0.0), ("pressure_range_bar", (5.0, 1.5)),
    ("pressure_range_bar", (1.5,)), ("pressure_range_bar", "3"), ("pressure_range_bar", (-1.0, 3.0)),
    ("duty_range_pct", (10.0, 120.0)), ("valve", "ball"), ("control", "pid"), ("pwm_hz", 50.0),
    ("pwm_hz", True), ("flow_meter_pulses_per_l", -1.0), ("flow_meter_error_pct", 80.0),
    ("flow_meter_error_pct", float("nan")),
])
def test_bad_keys_name_key_and_value(key, value):
    with pytest.raises(VehicleError) as err:
        SprayerSpec(**{key: value})
    msg = str(err.value)
    assert "\n" not in msg and f"sprayer: {key}" in msg and repr(value)[:4] in msg


def test_pwm_pressure_must_be_within_the_nozzle_range_under_pwm_only():
    SprayerSpec(pwm_pressure_bar=6.0)                        # flow control: not used
    with pytest.raises(VehicleError, match=r"sprayer: pwm_pressure_bar .*got 6\.0"):
        SprayerSpec(control="pwm", pwm_pressure_bar=6.0)


def test_bad_rates_and_speeds():
    spec = SprayerSpec()
    with pytest.raises(VehicleError, match="lowest rate"):
        spec.speed_range_m_s(0.0)
    with pytest.raises(VehicleError, match="highest rate"):
        spec.speed_range_m_s(200.0, 100.0)
    with pytest.raises(VehicleError, match="working speed"):
        spec.suggest_nozzle(100.0, 200.0, 0.0)
