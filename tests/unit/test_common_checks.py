"""The one number check every package uses: finite, not a bool, within bounds, named in the error."""

import math

import numpy as np
import pytest

from vrsim.common import MapError, VehicleError, check_number, check_positive, is_number


@pytest.mark.parametrize("value, ok", [(1, True), (2.5, True), (np.float32(1.5), True), (np.int64(3), True),
                                       (True, False), (np.bool_(True), False), (math.nan, False),
                                       (math.inf, False), ("1", False), (None, False)])
def test_is_number(value, ok):
    assert is_number(value) is ok


def test_check_positive_names_owner_key_rule_and_value():
    assert check_positive(np.float64(2.0), "Implement: width_m", VehicleError) == 2.0
    for bad in (0, -1.0, math.nan, True, "3"):
        with pytest.raises(VehicleError, match=r"^Implement: width_m must be a number > 0, got "):
            check_positive(bad, "Implement: width_m", VehicleError)
    with pytest.raises(MapError, match=r"cell_size_m must be a number > 0 m, got -2"):
        check_positive(-2, "x: cell_size_m", MapError, unit="m")


@pytest.mark.parametrize("kwargs, value, message", [
    (dict(lo=0.0), -0.5, "must be a number >= 0, got -0.5"),
    (dict(lo=0.0, hi=50.0), 51, "must be a number in [0, 50], got 51"),
    (dict(lo=0.0, hi=100.0, lo_open=True), 0.0, "must be a number in (0, 100], got 0.0"),
    (dict(hi=1.0), 2.0, "must be a number <= 1, got 2.0"),
    (dict(), math.inf, "must be a finite number, got inf"),
])
def test_check_number_bounds(kwargs, value, message):
    with pytest.raises(MapError) as err:
        check_number(value, "k", MapError, **kwargs)
    assert str(err.value) == "k " + message
    assert check_number(kwargs.get("hi", 1.0), "k", MapError, **kwargs) == kwargs.get("hi", 1.0)
