"""The sprayer kind's run-time part (services/sim/machines/sprayer.py) and its machine check
(services/sim/limits.py) without SUMO: targets, nozzles per section, kg per metered litre, limits."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from vrsim.common import VehicleError
from vrsim.services.sim.limits import machine_check
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.sections.motion import Motion
from vrsim.services.sim.sections.switching import SectionStates
from vrsim.vehicle import Implement
from vrsim.vehicle.product import Product
from vrsim.vehicle.sprayer import SprayerSpec, boom_flow_l_min


def _sprayer(**keys) -> Implement:
    return Implement(width_m=12.0, sections=6, kind="sprayer", machine=SprayerSpec(**keys))


def _states(imp: Implement, speed_m_s, yaw_rad_s, on=None) -> SectionStates:
    n = len(speed_m_s)
    zeros = np.zeros(n)
    motion = Motion(zeros, zeros, zeros, np.asarray(speed_m_s, float), zeros, np.asarray(yaw_rad_s, float))
    actual = np.ones((n, imp.sections), bool) if on is None else np.asarray(on, bool)
    return SectionStates(actual, imp.section_widths, imp.section_offsets_m, np.zeros(n, int), actual, motion)


def test_each_section_holds_its_nozzles_and_a_litre_is_its_density_over_the_meters_gain():
    machine = machine_for(_sprayer(nozzle="04", flow_meter_error_pct=5.0))
    assert machine.nozzles_per_section.tolist() == [4] * 6
    assert machine.nozzle_section.tolist() == [s for s in range(6) for _ in range(4)]
    assert machine.drives == 1
    assert machine.kg_per_rev(Product(form="liquid", density_kg_l=1.2)) == pytest.approx(1.2 / 1.05)


def test_flow_control_targets_the_open_nozzles_flow_held_in_their_pressure_range():
    imp = _sprayer(nozzle="04")
    machine = machine_for(imp)
    on = np.ones((3, 6), bool)
    on[1, :3] = False                                      # half the boom shut
    rate = np.array([[200.0], [200.0], [10.0]])            # 10 L/ha needs less than 1.5 bar gives
    target = machine.drive_targets(rate, _states(imp, [2.5, 2.5, 2.5], [0.0, 0.0, 0.0], on))[:, 0]
    assert target[0] == pytest.approx(boom_flow_l_min(200.0, 2.5, 12.0))
    assert target[1] == pytest.approx(boom_flow_l_min(200.0, 2.5, 6.0))
    assert target[2] == pytest.approx(24 * SprayerSpec(nozzle="04").nozzle_flow_range_l_min()[0])
    limited = machine.limited({"drive_target_rpm": target[:, None], "sections_on": on})
    assert limited.tolist() == [False, False, True]


def test_pwm_gives_each_section_its_nozzles_flow_at_their_own_speed_in_a_turn():
    imp = _sprayer(nozzle="05", control="pwm", pwm_pressure_bar=4.0)
    machine = machine_for(imp)
    assert machine.drives == 6 and machine.drive_share.tolist() == [1.0] * 6
    speed, radius = 2.5, 20.0
    target = machine.drive_targets(np.full((1, 6), 200.0), _states(imp, [speed], [speed / radius]))[0]
    # a left turn: section i's nozzles move at v (r_i / R), r_i = R - offset, so the flow follows the radius
    radius_i = radius - imp.section_offsets_m
    assert target == pytest.approx(boom_flow_l_min(200.0, speed * radius_i / radius, 2.0))
    assert machine.combined(target[None, :])[0] == pytest.approx(boom_flow_l_min(200.0, speed, 12.0))


def test_a_boom_the_nozzles_do_not_fit_is_named():
    assert "does not divide" in machine_for(_sprayer(nozzle_spacing_m=0.7)).layout_error
    imp = Implement(width_m=12.0, sections=5, kind="sprayer")
    assert "section 3 (2.4 m) is not a whole number of nozzle_spacing_m" in machine_for(imp).layout_error


def test_the_machine_check_names_the_speeds_and_the_nozzle_that_would_do():
    wide = _sprayer(nozzle="04", pressure_range_bar=(1.0, 8.0))      # air-induction nozzles: 1-8 bar
    check = machine_check(np.array([130.0, 278.0]), (2.38, 2.62), wide, 1.0, 2.5)
    assert check.can_apply and "the sprayer can apply the map: 130-278 L/ha (130-278 kg/ha)" in check.text()
    lo, hi = SprayerSpec(nozzle="04", pressure_range_bar=(1.0, 8.0)).speed_range_m_s(130.0, 278.0)
    assert (check.min_speed_m_s, check.max_speed_m_s) == pytest.approx((lo, hi))
    assert check.rpm_max == pytest.approx(boom_flow_l_min(278.0, 2.62, 12.0))
    pwm = _sprayer(nozzle="02", control="pwm")                 # 02 nozzles are too small at 2.5 m/s
    check = machine_check(np.array([130.0, 278.0]), (2.38, 2.62), pwm, 1.0, 2.5)
    assert not check.can_apply
    # the nearest size that applies it at every working speed (not the most centred, '08')
    assert "set [implement] nozzle = '06' (now '02') to apply it at 2.38-2.62 m/s." in check.text()
    # 2.6 kg/L: the same kg/ha are 2.6 times fewer litres
    dense = machine_check(np.array([130.0, 278.0]), (2.38, 2.62), pwm, 2.6, 2.5)
    assert dense.rpm_max == pytest.approx(check.rpm_max / 2.6)
    assert math.isnan(machine_check(np.array([0.0]), (2.38, 2.62), pwm).rate_max_kg_ha)


def test_a_nozzle_that_cannot_cover_the_map_at_any_speed_is_one_line():
    with pytest.raises(VehicleError) as err:
        machine_check(np.array([130.0, 278.0]), (2.38, 2.62), _sprayer(nozzle="02"))
    msg = str(err.value)
    assert "\n" not in msg and "nozzle '02'" in msg and "at any speed" in msg and 'control = "pwm"' in msg


def test_pwm_lands_each_sections_own_product_and_flow_control_the_booms():
    on = np.array([[True, True, False, False, False, False]])
    own = np.array([[1.0, 3.0, 0.0, 0.0, 0.0, 0.0]])
    control = {"drive_kg": own, "metered_kg": own.sum(axis=1), "sections_on": on}
    assert machine_for(_sprayer(control="pwm")).deposit_kg(control) == pytest.approx(own)
    assert machine_for(_sprayer()).deposit_kg(control) == pytest.approx([4.0])


def test_a_shaft_key_set_on_a_sprayer_is_refused_and_as_run_files_leave_them_out():
    from vrsim.common import ScenarioError
    from vrsim.services.sim import scenario
    from vrsim.services.sim.machines.keys import implement_from_table, implement_table

    with pytest.raises(ScenarioError, match=r"x.toml: \[implement\] kg_per_rev is not a key of kind 'spr"):
        implement_from_table({"kind": "sprayer", "kg_per_rev": 0.8}, "x.toml")
    # at the default (a granular file whose kind --set changes) it changes nothing
    assert implement_from_table({"kind": "sprayer", "kg_per_rev": 0.5}, "x.toml").kind == "sprayer"
    sprayer = scenario.with_changes(scenario.load("default"), implement={"kind": "sprayer", "nozzle": "08"})
    assert "kg_per_rev" not in implement_table(sprayer.implement)
    assert implement_table(sprayer.implement)["nozzle"] == "08"


def _uan_loop(imp: Implement, rate_l_ha: float, density_kg_l: float = 1.28):
    """`imp`'s sprayer with its loop built for a product of `density_kg_l` on a map of `rate_l_ha`."""

    from vrsim.controller import PlantParams

    machine = machine_for(imp)
    sc = SimpleNamespace(source="uan.toml", product=Product(form="liquid", density_kg_l=density_kg_l),
                         tractor=SimpleNamespace(working_speed_m_s=2.5))
    grid = SimpleNamespace(rates_kg_ha=np.array([rate_l_ha * density_kg_l]))
    machine.loop_plant(PlantParams(), sc, grid)
    return machine, sc


def test_uan_moves_the_booms_orifice_its_targets_range_and_the_machine_check():
    """UAN 28 % at 1.28 kg/L through 04 nozzles at 1-5 bar: each passes sqrt(1 / 1.28) of its water rating
    at a pressure (1.414 L/min at 3 bar), the loop's plant, the targets' clip, the limited ticks and the
    machine check (flows, speeds, nozzle advice) all with it."""
    f = math.sqrt(1 / 1.28)
    imp = _sprayer(nozzle="04", pressure_range_bar=(1.0, 5.0))
    water = SprayerSpec(nozzle="04", pressure_range_bar=(1.0, 5.0)).nozzle_flow_range_l_min()
    machine, sc = _uan_loop(imp, 190.0)
    fp, _ = machine.flow_linearization(sc, SimpleNamespace(rates_kg_ha=np.array([190.0 * 1.28])))
    assert fp.boom_coeff_l_min_bar == pytest.approx(24 * 1.6 * f / math.sqrt(3.0))
    assert fp.pressure_bar(24 * 1.414) == pytest.approx(3.0, abs=0.005)       # 24 nozzles' 1.414 L/min
    assert fp.pressure_bar(24 * water[1] * f) == pytest.approx(5.0)
    # 10 L/ha: below the low end, held at 1 bar's flow of UAN; 0.9 L/min a nozzle is within UAN's range
    # (0.82-1.83) though below water's (0.92-2.07); 2 L/min beyond it
    need = np.array([0.9, 2.0]) / boom_flow_l_min(1.0, 2.5, 0.5)             # L/ha for those flows
    rate_kg = np.array([[10.0], [need[0]], [need[1]]]) * 1.28
    target = machine.drive_targets(rate_kg, _states(imp, [2.5] * 3, [0.0] * 3))[:, 0]
    assert target == pytest.approx([24 * water[0] * f, 24 * 0.9, 24 * water[1] * f])
    control = {"drive_target_rpm": target[:, None], "sections_on": np.ones((3, 6), bool)}
    assert machine.limited(control).tolist() == [True, False, True]
    uan = Product(form="liquid", density_kg_l=1.28)
    assert machine_for(imp).limited(control, uan).tolist() == [True, False, True]
    # the check: rates in kg/ha are L/ha x 1.28; the nozzles' flows and speeds are water's times f
    dry = machine_check(np.array([160.0, 220.0]), (2.38, 2.62), imp, 1.0, 2.5)
    wet = machine_check(np.array([160.0, 220.0]) * 1.28, (2.38, 2.62), imp, 1.28, 2.5)
    assert wet.nozzle_flow_min_l_min == pytest.approx(water[0] * f)
    assert wet.nozzle_flow_max_l_min == pytest.approx(water[1] * f)
    assert wet.shaft_rpm_max == pytest.approx(24 * water[1] * f)
    assert wet.min_speed_m_s == pytest.approx(dry.min_speed_m_s * f)
    assert wet.max_speed_m_s == pytest.approx(dry.max_speed_m_s * f)
    assert wet.rpm_max == pytest.approx(dry.rpm_max)                          # the same litres
    # water's best size is the 04 on the boom: advice never names the setting in place
    assert (dry.nozzle_suggested, wet.nozzle_suggested) == (None, "05")
    assert "giving 19.6-43.8 L/min of a 1.28 kg/L liquid (0.884 times water's)." in wet.text()
    assert "kg/L" not in dry.text() and "giving 22.2-49.6 L/min.\n" in dry.text()


def test_pwm_opens_each_nozzle_to_its_flow_of_the_liquid():
    f = math.sqrt(1 / 1.28)
    imp = _sprayer(nozzle="05", control="pwm", pwm_pressure_bar=4.0)
    machine, _ = _uan_loop(imp, 200.0)
    q_open = 2.0 * math.sqrt(4.0 / 3.0) * f                                   # 2.04 L/min of UAN at 4 bar
    # a section's 4 nozzles: 2.2 L/min each is more than fully open; 1.5 L/min a duty of 73 %
    need = np.array([2.2, 1.5]) / boom_flow_l_min(1.0, 2.5, 0.5)
    target = machine.drive_targets(np.repeat(need[:, None], 6, axis=1) * 1.28,
                                   _states(imp, [2.5, 2.5], [0.0, 0.0]))
    assert target == pytest.approx(np.array([[4 * q_open] * 6, [4 * 1.5] * 6]))
    uan = Product(form="liquid", density_kg_l=1.28)
    unlimited = machine.unlimited_targets(np.repeat(need[:, None], 6, axis=1) * 1.28,
                                          _states(imp, [2.5, 2.5], [0.0, 0.0]), uan)
    assert unlimited == pytest.approx(np.array([[4 * 2.2] * 6, [4 * 1.5] * 6]))


def test_the_catch_test_catches_the_liquids_flow_at_3_bar():
    """`vrsim calibrate`'s boom sprays the product: 24 06 nozzles give 57.6 L of water in a minute at 3 bar,
    sqrt(1 / 1.28) of that of UAN; the meter's constant measured is the same."""
    import os

    from tests.conftest import ROOT
    from vrsim.services.sim import scenario
    from vrsim.services.sim.calibrate import calibrate

    path = os.path.join(ROOT, "scenarios", "sprayer.toml")
    water = calibrate(scenario.load(path), seconds=60.0, jug_error_ml=0.0)
    uan = calibrate(scenario.load(path, [("product.density_kg_l", 1.28)]), seconds=60.0, jug_error_ml=0.0)
    assert water.caught_l == pytest.approx(24 * 2.4)
    assert uan.caught_l == pytest.approx(24 * 2.4 * math.sqrt(1 / 1.28))
    assert uan.measured_pulses_per_l == pytest.approx(600.0, rel=1e-4)
