"""Fixtures of the integration tests that drive SUMO on a small rectangle."""

import pytest

from vrsim.vehicle import Field, plan_coverage


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A SUMO network cache for the module's drives."""
    return str(tmp_path_factory.mktemp("sumo-cache"))


@pytest.fixture(scope="module")
def rect_path():
    """Coverage of a 120 m x 200 m rectangle at 12 m with one headland pass."""
    return plan_coverage(Field.rectangle(120.0, 200.0), 12.0, headland_passes=1)
