"""The user's own units (`maps.units`): the one table of display units and its conversion, the system a
map's rate unit implies, and lengths, speeds and pressures given with a unit in a scenario (read with the
bounded grammar, SI inside; a unit of the wrong kind or one pint cannot read refused naming key and value)."""

import math

import pytest

from vrsim.common import ScenarioError
from vrsim.maps.units import US_UNITS, in_units, quantity_in, shown_range, shown_text, unit_system
from vrsim.services.sim.scenario import parse

FT_M, IN_M, MI_M = 0.3048, 0.0254, 1609.344  # international foot, inch, mile
LB_KG, GAL_L = 0.45359237, 3.785411784       # avoirdupois pound, US gallon
PSI_BAR = LB_KG * 9.80665 / IN_M**2 / 1e5     # pound-force per square inch
AC_HA = 43560 * FT_M**2 / 1e4


@pytest.mark.parametrize("unit, us, one_us_in_metric", [
    ("kg", "lb", LB_KG), ("ha", "ac", AC_HA), ("m", "ft", FT_M), ("m/s", "mph", MI_M / 3600),
    ("km/h", "mph", MI_M / 1000), ("L", "gal", GAL_L), ("mL", "floz", GAL_L * 1000 / 128),
    ("L/min", "gpm", GAL_L), ("bar", "psi", PSI_BAR), ("kPa", "psi", PSI_BAR * 100),
    ("kg/ha", "lb/ac", LB_KG / AC_HA), ("L/ha", "gal/ac", GAL_L / AC_HA), ("seeds/ha", "seeds/ac", 1 / AC_HA),
])
def test_the_table_converts_each_metric_unit_to_its_us_one_by_the_defined_factors(unit, us, one_us_in_metric):
    assert US_UNITS[unit] == us
    value, shown = in_units(one_us_in_metric, unit, "us")
    assert shown == us and value == pytest.approx(1.0, rel=1e-12)
    assert in_units(one_us_in_metric, unit, "metric") == (one_us_in_metric, unit)  # metric: as computed


def test_a_us_unit_in_metric_is_its_first_metric_counterpart_and_other_units_stay():
    for us, metric in (("gal/ac", "L/ha"), ("lb/ac", "kg/ha"), ("mph", "m/s"), ("psi", "bar"), ("ft", "m")):
        assert in_units(1.0, us, "metric")[1] == metric
    assert in_units(10.0, "gal/ac", "metric")[0] == pytest.approx(10 * GAL_L / AC_HA, rel=1e-12)
    for unit in ("%", "s", "rpm", "", "x"):
        assert in_units(3.5, unit, "us") == (3.5, unit)


def test_lists_nan_and_non_numbers_convert_or_pass_through():
    widths, unit = in_units([6.096, 12.192], "m", "us")
    assert unit == "ft" and widths == pytest.approx([20.0, 40.0], rel=1e-12)
    assert math.isnan(in_units(float("nan"), "kg", "us")[0])
    assert in_units(None, "kg", "us") == (None, "kg") and in_units("n/a", "m", "us") == ("n/a", "m")
    assert shown_text(4.4704, "m/s", "us") == "10.00 mph"
    assert shown_range(2.0, 3.0, "bar", "us", ".1f") == "29.0-43.5 psi"


@pytest.mark.parametrize("map_unit, units, system", [
    ("gal/ac", None, "us"), ("lb/ac", None, "us"), ("seeds/ac", None, "us"), ("kg/ha", None, "metric"),
    ("L/ha", None, "metric"), (None, None, "metric"), ("gal/ac", "metric", "metric"), ("kg/ha", "us", "us"),
])
def test_the_system_follows_the_maps_rate_unit_unless_output_units_says(map_unit, units, system):
    assert unit_system(map_unit, units) == system


@pytest.mark.parametrize("text, unit, kind, si", [
    ("120 ft", "m", "length", 120 * FT_M), ("120ft", "m", "length", 120 * FT_M),
    ("20 in", "m", "length", 20 * IN_M), ("10 mph", "m/s", "speed", 10 * MI_M / 3600),
    ("12 km/h", "m/s", "speed", 12 / 3.6), ("15 psi", "bar", "pressure", 15 * PSI_BAR),
    ("300 kPa", "bar", "pressure", 3.0), ("  2.5e1 m ", "m", "length", 25.0),
])
def test_a_number_with_a_unit_reads_into_the_keys_unit(text, unit, kind, si):
    assert quantity_in(text, unit, kind) == pytest.approx(si, rel=1e-11)


def test_a_typed_foot_is_the_metres_a_user_would_type():
    assert quantity_in("120 ft", "m", "length") == 36.576  # to 12 digits, not 36.575999999999993


@pytest.mark.parametrize("text, kind, says", [
    ("120 kg", "length", "is not a length"), ("10 m/s2", "speed", "is not a speed"),
    ("15 ha", "pressure", "is not a pressure"), ("120 furlongz", "length", "pint does not read"),
    ("9**9**9 m", "length", "not a unit vrsim reads"), ("ft", "length", "not a number with a unit"),
    ("120", "length", "not a number with a unit"), ("1e999 ft", "length", "not a finite length"),
    ("1" * 300 + " ft", "length", "is not a length"),
])
def test_a_bad_quantity_says_why(text, kind, says):
    unit = {"length": "m", "speed": "m/s", "pressure": "bar"}[kind]
    with pytest.raises(ValueError, match=says):
        quantity_in(text, unit, kind)


SPRAYER = """name = "boom"
[field]
rectangle = {{ width = "500 ft", length_m = 200.0, lat = 48.2, lon = 11.6 }}
[map]
synthetic = "uniform"
[implement]
kind = "sprayer"
nozzle = "04"
{implement}
[tractor]
{tractor}
[product]
form = "liquid"
density_kg_l = 1.0
{output}
"""


def sprayer(implement='width = "120 ft"\nnozzle_spacing = "20 in"\npressure_range = ["20 psi", "75 psi"]',
            tractor='working_speed = "10 mph"', output=""):
    return parse(SPRAYER.format(implement=implement, tractor=tractor, output=output), "boom.toml")


def test_scenario_lengths_speeds_and_pressures_with_a_unit_are_si_inside():
    sc = sprayer()
    assert sc.implement.width_m == 36.576 and sc.field.rectangle["width_m"] == 152.4
    assert sc.implement.machine.nozzle_spacing_m == 0.508
    assert sc.implement.machine.pressure_range_bar == pytest.approx([20 * PSI_BAR, 75 * PSI_BAR], rel=1e-11)
    assert sc.tractor.working_speed_m_s == 4.4704
    # The key with its unit's ending takes a unit string too; a plain number there is in that unit.
    same = sprayer('width_m = "120 ft"\nnozzle_spacing_m = 0.508\npressure_range_bar = ["20 psi", 5.0]',
                   'working_speed_m_s = "16.09344 km/h"')
    assert same.implement.width_m == 36.576 and same.tractor.working_speed_m_s == 4.4704
    assert same.implement.machine.pressure_range_bar[1] == 5.0


@pytest.mark.parametrize("implement, tractor, says", [
    ('width = "120 kg"', "", "[implement] width '120 kg' is not a length"),
    ('width_m = "120 furlongz"', "", "[implement] width_m '120 furlongz' has a unit pint does not read"),
    ('pressure_range = ["20 psi", "75 mph"]', "", "[implement] pressure_range ['20 psi', '75 mph'] is not a "
                                                  "pressure"),
    ("", 'working_speed = "fast"', "[tractor] working_speed 'fast' is not a number with a unit of speed"),
    ("", 'working_speed = "9**9**9 mph"', "[tractor] working_speed '9**9**9 mph'"),
    ('width = "120 ft"\nwidth_m = 30.0', "", "[implement] width and width_m: give one of them"),
])
def test_a_bad_unit_string_is_one_line_naming_file_key_and_value(implement, tractor, says):
    with pytest.raises(ScenarioError) as err:
        sprayer(implement, tractor)
    message = str(err.value)
    assert message.startswith("boom.toml: ") and says in message and "\n" not in message


def test_output_units_is_metric_us_or_unset():
    assert sprayer().output.units is None
    assert sprayer(output='[output]\nunits = "us"').output.units == "us"
    with pytest.raises(ScenarioError, match=r"\[output\] units must be one of metric, us, got 'imperial'"):
        sprayer(output='[output]\nunits = "imperial"')
