"""The product a meter meters (`vehicle.product`): its checks, its true constant, its flow variability."""

import json

import numpy as np
import pytest

from vrsim.common.errors import VehicleError
from vrsim.vehicle.product import Product, _flow_factors, metered_kg

REV = np.random.default_rng(0).uniform(0.0, 0.12, 4000)   # forward revolutions per tick (0-144 rpm at 20 Hz)


def test_the_default_product_meters_the_configured_constant_bitwise():
    kg, end = metered_kg(REV, 0.5, Product(), seed=1)
    np.testing.assert_array_equal(kg, REV * 0.5)
    assert end == pytest.approx(REV.sum(), rel=1e-12)


def test_a_calibration_error_scales_the_product_by_the_true_constant():
    product = Product(calibration_error_pct=5.0)
    assert product.true_kg_per_rev(0.5) == pytest.approx(0.525, rel=1e-15)
    kg, _ = metered_kg(REV, 0.5, product, seed=1)
    np.testing.assert_allclose(kg, REV * 0.525, rtol=1e-15)


def test_flow_factors_have_mean_one_and_the_cv_and_do_not_depend_on_how_many_are_drawn():
    factors = _flow_factors(Product(flow_cv_pct=8.0), seed=4, count=200_000)
    assert factors.mean() == pytest.approx(1.0, abs=0.001)
    assert factors.std() / factors.mean() == pytest.approx(0.08, rel=0.02)
    assert (factors > 0).all()
    np.testing.assert_array_equal(_flow_factors(Product(flow_cv_pct=8.0), seed=4, count=37), factors[:37])
    assert not np.array_equal(_flow_factors(Product(flow_cv_pct=8.0), seed=5, count=37), factors[:37])


def test_flow_variability_holds_per_revolution_and_keeps_the_total_of_whole_revolutions():
    product = Product(flow_cv_pct=10.0, calibration_error_pct=-3.0)
    factors = _flow_factors(product, seed=2, count=10)
    # Ticks of a quarter revolution: four ticks per revolution carry the same factor.
    kg, end = metered_kg(np.full(40, 0.25), 1.0, product, seed=2)
    np.testing.assert_allclose(kg.reshape(10, 4), np.repeat(factors[:, None], 4, axis=1) * 0.25 * 0.97,
                               rtol=1e-12)
    # A tick across a revolution's end takes each revolution's share.
    kg, _ = metered_kg(np.array([0.7, 0.6]), 1.0, product, seed=2)
    assert kg[1] == pytest.approx((0.3 * factors[0] + 0.3 * factors[1]) * 0.97, rel=1e-12)
    assert end == pytest.approx(10.0)


def test_any_split_into_batches_meters_bitwise_the_same_also_after_json_and_in_columns():
    product = Product(flow_cv_pct=6.0, calibration_error_pct=4.0)
    whole, end = metered_kg(REV, 0.5, product, seed=9)
    parts, start = [], 0.0
    for part in np.split(REV, [1, 2, 700, 701, 2500]):
        kg, start = metered_kg(part, 0.5, product, seed=9, start_rev=start)
        start = json.loads(json.dumps(float(start)))   # the controller service's state goes as JSON
        parts.append(kg)
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    assert start == end
    columns, ends = metered_kg(np.column_stack([REV, REV]), 0.5, product, seed=9, start_rev=np.zeros(2))
    np.testing.assert_array_equal(columns[:, 1], whole)
    np.testing.assert_array_equal(ends, [end, end])
    # On average the variability leaves the product as the true constant gives it (4000 ticks: ~240 revs).
    assert whole.sum() == pytest.approx(REV.sum() * 0.52, rel=0.02)


@pytest.mark.parametrize("changes, message", [
    ({"form": "gas"}, "form must be one of granular, liquid, got 'gas'"),
    ({"density_kg_l": -1.0}, "density_kg_l must be a number in (0, 25] kg/L, got -1.0"),
    ({"density_kg_l": 0.0}, "density_kg_l must be a number in (0, 25] kg/L, got 0.0"),
    ({"flow_cv_pct": -0.1}, "flow_cv_pct must be a number in [0, 50] %, got -0.1"),
    ({"flow_cv_pct": 51.0}, "flow_cv_pct must be a number in [0, 50] %, got 51.0"),
    ({"calibration_error_pct": -50.0}, "calibration_error_pct must be a number in (-50, 100) %, got -50.0"),
    ({"calibration_error_pct": 100.0}, "calibration_error_pct must be a number in (-50, 100) %, got 100.0"),
    ({"calibration_error_pct": float("nan")}, "calibration_error_pct must be a number in (-50, 100) %"),
])
def test_bad_values_are_refused_naming_key_and_value(changes, message):
    with pytest.raises(VehicleError) as err:
        Product(**changes)
    assert message in str(err.value)
