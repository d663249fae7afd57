"""The operator's calibration test, simulated (`services.sim.calibrate`)."""

import numpy as np
import pytest

from vrsim.common import ScenarioError, VrsimError
from vrsim.services.sim import scenario
from vrsim.services.sim.calibrate import _CATCH_STREAM, calibrate
from vrsim.vehicle.product import Product, _flow_factors


def cal5(**product):
    return scenario.load("default", [("product.calibration_error_pct", 5.0),
                                      *((f"product.{k}", v) for k, v in product.items())])


def test_a_perfect_scale_and_even_flow_measure_the_true_constant():
    result = calibrate(cal5(), revolutions=50, scale_error_g=0.0)
    assert result.measured_kg_per_rev == pytest.approx(0.525, rel=1e-12)
    assert result.true_kg_per_rev == pytest.approx(0.525, rel=1e-15)
    assert result.change_pct == pytest.approx(5.0, rel=1e-9)
    assert result.settings == {"implement.kg_per_rev": 0.525, "product.calibration_error_pct": 0.0}
    assert result.weighed_kg == pytest.approx(26.25)
    assert "--set implement.kg_per_rev=0.525 --set product.calibration_error_pct=0" in result.text()


def test_the_catch_is_the_flow_factors_of_its_revolutions_and_the_scale_reads_it_with_its_error():
    sc = cal5(flow_cv_pct=5.0)
    result = calibrate(sc, revolutions=40, scale_error_g=0.0)
    factors = _flow_factors(sc.product, sc.seed, 40, stream=_CATCH_STREAM)
    assert result.caught_kg == pytest.approx(0.525 * factors.sum(), rel=1e-12)
    assert calibrate(sc, revolutions=40, scale_error_g=0.0) == result   # seeded
    weighed = calibrate(sc, revolutions=40, scale_error_g=50.0)
    assert weighed.caught_kg == result.caught_kg and 0 < abs(weighed.weighed_kg - weighed.caught_kg) < 0.25
    # The field's revolutions and the test's are different revolutions.
    assert not np.array_equal(factors, _flow_factors(sc.product, sc.seed, 40))


def test_more_revolutions_measure_the_constant_closer_over_many_seeds():
    def spread(revolutions):
        errors = [calibrate(scenario.load("default", [("seed", seed), ("product.flow_cv_pct", 10.0)]),
                            revolutions, 20.0).change_pct for seed in range(40)]
        return np.sqrt(np.mean(np.square(errors)))
    few, many = spread(5), spread(200)
    assert many < few / 3   # the flow's mean over n revolutions: 10 % / sqrt(n)
    assert few == pytest.approx(10.0 / np.sqrt(5), rel=0.35) and many < 1.5


def test_the_remaining_error_is_what_the_same_meter_has_against_the_new_constant():
    result = calibrate(cal5(flow_cv_pct=3.0), revolutions=50, scale_error_g=20.0)
    kg, error = result.settings.values()
    assert Product(calibration_error_pct=error).true_kg_per_rev(kg) == pytest.approx(0.525, rel=1e-4)


def test_a_liquid_product_needs_the_sprayer_kind_and_bad_options_are_named():
    with pytest.raises(ScenarioError, match=r"default.toml: \[product\] form 'liquid': .*sprayer"):
        calibrate(cal5(form="liquid"))
    with pytest.raises(VrsimError, match=r"--revolutions 0: must be"):
        calibrate(cal5(), revolutions=0)
    with pytest.raises(VrsimError, match=r"--scale-error-g -1.0: must be"):
        calibrate(cal5(), scale_error_g=-1.0)
    refused = 0
    for seed in range(8):   # a scale whose error swamps a 0.5 kg catch reads below nothing half the time
        try:
            calibrate(scenario.load("default", [("seed", seed)]), revolutions=1, scale_error_g=90_000.0)
        except VrsimError as exc:
            assert "the scale read" in str(exc) and "weigh more revolutions" in str(exc)
            refused += 1
    assert 0 < refused < 8
