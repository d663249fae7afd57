"""The machine check before a run (`services.sim.limits`): can the meter apply the map at the speeds?"""

import math

import numpy as np
import pytest

from vrsim.services.sim.limits import machine_check, working_speeds
from vrsim.vehicle import DriveConfig, Implement


def test_held_out_boom_too_fast_for_its_shaft():
    # An 18 m boom at 3.6 m/s on a map asking up to 260 kg/ha: 260 * 3.6 * 18 / 1e4 / 0.5 * 60 = 202 rpm
    # of a 150 rpm shaft.
    imp = Implement(width_m=18.0, sections=6, kg_per_rev=0.5, shaft_rpm_max=150.0)
    rates = np.array([[np.nan, 0.0, 140.0], [200.0, 259.8, 180.0]])
    check = machine_check(rates, (3.6, 3.6), imp)
    assert not check.can_apply
    assert (check.rate_min_kg_ha, check.rate_max_kg_ha) == (140.0, 259.8)
    assert check.rpm_max == pytest.approx(202.0, abs=0.1)
    # The highest speed at which it can: 150 rpm at 259.8 kg/ha over 18 m.
    assert check.max_speed_m_s == pytest.approx(150 * 0.5 * 1e4 / 60 / (259.8 * 18), rel=1e-12)
    assert imp.target_shaft_rpm(259.8, check.max_speed_m_s, 18.0) == pytest.approx(150.0, rel=1e-12)
    text = check.text()
    assert "CANNOT apply" in text and "202.0 rpm of a 5-150 rpm shaft" in text
    assert f"{check.max_speed_m_s:.2f} m/s" in text and "under-applied" in text


def test_a_machine_that_can_and_its_speed_range():
    imp = Implement()  # 12 m, 0.5 kg/rev, 5-150 rpm
    check = machine_check(np.array([120.0, 278.0]), (2.375, 2.625), imp)
    assert check.can_apply and "can apply the map" in check.text()
    assert check.min_speed_m_s == pytest.approx(5 * 0.5 * 1e4 / 60 / (120 * 12))
    assert check.min_speed_m_s < 2.375 and check.max_speed_m_s > 2.625
    # Slow enough, the lowest rate needs less than the shaft's minimum.
    slow = machine_check(np.array([120.0, 278.0]), (0.2, 2.625), imp)
    assert not slow.can_apply and "over-applied" in slow.text()


def test_no_product_asked_for():
    check = machine_check(np.array([0.0, np.nan]), (2.0, 3.0), Implement())
    assert check.can_apply and math.isnan(check.max_speed_m_s) and "no product" in check.text()


def test_working_speeds_span_the_variation_and_the_headland_speed():
    assert working_speeds(DriveConfig(working_speed_m_s=2.0, speed_variation_pct=10.0)) == \
        pytest.approx((1.8, 2.2))
    assert working_speeds(DriveConfig(working_speed_m_s=2.0, speed_variation_pct=0.0,
                                      headland_speed_m_s=3.0)) == (2.0, 3.0)


def test_a_machine_that_cannot_is_told_the_speeds_and_the_meter_constants_with_which_it_can():
    imp = Implement(width_m=18.0, sections=6, kg_per_rev=0.5, shaft_rpm_max=150.0)
    check = machine_check(np.array([140.0, 259.8]), (3.0, 3.6), imp)
    assert not check.can_apply
    # At the constants' bounds the highest rate at the highest speed needs exactly the top of the
    # shaft's range, and the lowest at the lowest speed exactly its bottom.
    at_min = Implement(width_m=18.0, sections=6, kg_per_rev=check.kg_per_rev_min, shaft_rpm_max=150.0)
    at_max = Implement(width_m=18.0, sections=6, kg_per_rev=check.kg_per_rev_max, shaft_rpm_max=150.0)
    assert at_min.target_shaft_rpm(259.8, 3.6) == pytest.approx(150.0, rel=1e-12)
    assert at_max.target_shaft_rpm(140.0, 3.0) == pytest.approx(5.0, rel=1e-12)
    assert machine_check(np.array([140.0, 259.8]), (3.0, 3.6), at_min).can_apply
    assert machine_check(np.array([140.0, 259.8]), (3.0, 3.6), at_max).can_apply
    text = check.text()
    assert f"keep the working speeds within {check.min_speed_m_s:.2f}-{check.max_speed_m_s:.2f} m/s" in text
    assert (f"set [implement] kg_per_rev to {check.kg_per_rev_min:.4g}-{check.kg_per_rev_max:.4g} kg/rev "
            "(now 0.5: another roller or gear) to apply it at 3.00-3.60 m/s") in text
    # A machine that can is told nothing to change.
    assert "kg_per_rev" not in machine_check(np.array([120.0, 200.0]), (2.4, 2.6), Implement()).text()


def test_a_map_wider_than_the_shaft_has_no_speed_and_no_constant_that_applies_it():
    imp = Implement(shaft_rpm_min=10.0, shaft_rpm_max=150.0)   # a 15x range
    check = machine_check(np.array([10.0, 200.0]), (2.0, 3.0), imp)   # 20x the rates, 30x with speeds
    assert check.kg_per_rev_min > check.kg_per_rev_max and check.min_speed_m_s > check.max_speed_m_s
    text = check.text()
    assert "No working speed applies it all: the map's rates span 20.0x, the shaft's speeds 15.0x" in text
    assert "no meter constant applies it at 2.00-3.00 m/s" in text and "span 30.0x" in text
    # Without a lowest shaft speed any constant large enough does.
    free = machine_check(np.array([10.0, 200.0]), (2.0, 3.0), Implement(shaft_rpm_min=0.0))
    assert free.kg_per_rev_max == math.inf and free.can_apply
    fast = machine_check(np.array([10.0, 400.0]), (2.0, 4.0), Implement(shaft_rpm_min=0.0))
    assert not fast.can_apply and f"kg_per_rev to {fast.kg_per_rev_min:.4g} kg/rev or more" in fast.text()
