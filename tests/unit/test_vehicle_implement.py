import numpy as np
import pytest
import shapely

from common.errors import VehicleError
from vehicle import Implement


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
])
def test_validation_names_field_and_value(kwargs, match):
    with pytest.raises(VehicleError, match=match):
        Implement(**kwargs)
