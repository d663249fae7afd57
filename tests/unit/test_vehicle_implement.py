import dataclasses

import numpy as np
import pytest
import shapely

from vrsim.common.errors import VehicleError
from vrsim.vehicle import Implement


def test_target_shaft_rpm_formula_and_inverse():
    imp = Implement(width_m=12.0, kg_per_rev=0.5)
    # 200 kg/ha * 2.5 m/s * 12 m = 0.6 kg/s = 1.2 rev/s = 72 rpm
    assert imp.target_shaft_rpm(200.0, 2.5) == pytest.approx(72.0)
    rate = np.array([0.0, 100.0, 250.0])
    speed = np.array([2.0, 2.5, 3.0])
    rpm = imp.target_shaft_rpm(rate, speed)
    assert rpm.shape == (3,)
    # The inverse: what the shaft meters at that speed, over the area driven, is the rate.
    dt_s = 0.05
    metered_kg = imp.mass_kg(rpm / 60.0 * dt_s)
    assert np.allclose(metered_kg / (speed * dt_s * imp.width_m) * 1e4, rate)
    assert imp.target_shaft_rpm(200.0, 2.5, width_m=6.0) == pytest.approx(36.0)


def test_transmission_mass_and_clip():
    imp = Implement(transmission_ratio=0.2, kg_per_rev=0.5, shaft_rpm_min=5.0, shaft_rpm_max=150.0)
    assert imp.mass_kg(10.0) == pytest.approx(5.0)
    assert np.array_equal(imp.clip_shaft_rpm([0.0, 1.0, 80.0, 500.0]), [0.0, 5.0, 80.0, 150.0])


def test_sections_on_inside_field_only():
    imp = Implement(width_m=12.0, sections=6)
    assert np.allclose(imp.section_offsets_m, [5, 3, 1, -1, -3, -5])
    field = shapely.box(0, 0, 100, 100)
    on = imp.sections_on(field, [4.0, 50.0, 50.0, 96.0], [50.0] * 4, [np.pi / 2, np.pi / 2, 0.0, np.pi / 2],
                         [True, True, False, True])
    # Heading north at x=4: the two left sections (centres at x=-1, 1... left is west) are outside.
    assert on[0].tolist() == [False, True, True, True, True, True]
    assert on[1].all() and not on[2].any()
    assert on[3].tolist() == [True, True, True, True, True, False]


@pytest.mark.parametrize("kwargs, match", [
    (dict(width_m=0.0), "width_m must be a number > 0"),
    (dict(sections=0), "sections must be"),
    (dict(sections=2.5), "sections must be"),
    (dict(kg_per_rev=-0.1), "kg_per_rev"),
    (dict(transmission_ratio=float("inf")), "transmission_ratio"),
    (dict(shaft_rpm_min=200.0), "shaft_rpm_min=200.0 must be below"),
    (dict(delivery_delay_s=-1.0), "delivery_delay_s"),
    (dict(section_on_delay_s=-0.1), r"section_on_delay_s must be a number in \[0, 30\] s, got -0.1"),
    (dict(section_on_delay_s=float("nan")), "section_on_delay_s .* got nan"),
    (dict(section_off_delay_s=30.5), "section_off_delay_s .* got 30.5"),
    (dict(section_off_delay_s=float("inf")), "section_off_delay_s .* got inf"),
    (dict(section_min_speed_m_s=-0.1), r"section_min_speed_m_s must be a number in \[0, 5\] m/s, got -0.1"),
    (dict(section_min_speed_m_s=float("nan")), "section_min_speed_m_s .* got nan"),
    (dict(section_overlap_pct=-1.0), r"section_overlap_pct must be a number in \[0, 100\] %, got -1.0"),
    (dict(boundary_overlap_pct=100.5), "boundary_overlap_pct .* got 100.5"),
    (dict(section_overlap_pct=float("nan")), "section_overlap_pct .* got nan"),
    (dict(section_widths_m=[2.0, 4.0, 4.0]),
     r"section_widths_m \[2.0, 4.0, 4.0\] add up to 10 m, not width_m=12.0"),
    (dict(section_widths_m=[6.0, 0.0, 6.0]), r"section_widths_m\[1\] must be a number > 0, got 0.0"),
    (dict(section_widths_m=[6.0, "6"]), r"section_widths_m\[1\] must be a number > 0, got '6'"),
    (dict(section_widths_m=[]), "section_widths_m must be a list of 1 to 128 widths"),
    (dict(width_m=129.0, section_widths_m=[1.0] * 129), "section_widths_m must be a list of 1 to 128 widths"),
    (dict(sections=129), r"sections must be an integer in \[1, 128\], got 129"),
    (dict(sections=3, section_widths_m=[3.0, 3.0, 3.0, 3.0]), "sections=3 but section_widths_m has 4 widths"),
    (dict(section_control="manual"), "section_control must be one of coverage, boundary, off, got 'manual'"),
])
def test_validation_names_field_and_value(kwargs, match):
    with pytest.raises(VehicleError, match=match):
        Implement(**kwargs)


def test_section_defaults_and_count_form():
    imp = Implement()
    assert (imp.sections, imp.section_widths.tolist()) == (6, [2.0] * 6)
    assert (imp.section_control, imp.section_on_delay_s, imp.section_off_delay_s) == ("coverage", 1.0, 0.6)
    assert Implement(width_m=12.0, sections=4).section_widths.tolist() == [3.0, 3.0, 3.0, 3.0]
    wider = dataclasses.replace(imp, width_m=18.0)  # equal sections stay equal when the width changes
    assert (wider.sections, wider.section_widths.tolist()) == (6, [3.0] * 6)
    assert Implement(width_m=12.0, sections=128).sections == 128
    same = Implement(sections=3, section_widths_m=[3.0, 3.0, 6.0])
    assert same.sections == 3 and same.section_widths_m == (3.0, 3.0, 6.0)


def test_unequal_sections_offsets_and_boundary_test():
    imp = Implement(width_m=12.0, section_widths_m=[2.0, 4.0, 6.0])
    assert imp.sections == 3
    assert np.allclose(imp.section_widths, [2.0, 4.0, 6.0])
    assert np.allclose(imp.section_offsets_m, [5.0, 2.0, -3.0])  # left to right
    # Heading north at x = 7.5: the left section's centre (x = 2.5) is outside x >= 3.
    on = imp.sections_on(shapely.box(3, 0, 100, 100), [7.5], [50.0], [np.pi / 2])
    assert on.tolist() == [[False, True, True]]
