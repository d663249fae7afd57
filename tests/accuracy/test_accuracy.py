"""The accuracy library: every scenario must hold its recorded figures (tests/accuracy/expected.json).

The whole library runs once, in parallel across the cores, and each scenario is then one test so a
failure names it and prints the table of what moved.
"""

import pytest

from tests.integration.test_services_support import without_clock
from vrsim.services.sim import accuracy

NAMES = accuracy.scenario_names()
TIMING_KEYS = {"wall_time_s", "realtime_factor", "stage_s", "outputs_wall_s", "out_dir"}


@pytest.fixture(scope="module")
def results():
    return accuracy.run_library()


def test_library_has_at_least_ten_scenarios():
    assert len(NAMES) >= 10


def test_every_scenario_has_expected_figures():
    expected = accuracy.load_expected()
    missing = [n for n in NAMES if n not in expected]
    assert not missing, f"no expected figures for {missing}: run `vrsim accuracy --update --reason ...`"


@pytest.mark.parametrize("name", NAMES)
def test_scenario_holds_its_figures(results, name):
    checks = accuracy.compare(name, results[name], accuracy.load_expected())
    moved = [c for c in checks if c.moved]
    assert not moved, "figures moved beyond tolerance:\n" + accuracy.table(moved)


def test_same_scenario_and_seed_give_bitwise_identical_metrics(results):
    name = "uniform_rate" if "uniform_rate" in NAMES else NAMES[0]
    again = accuracy.run_scenario(name)
    assert without_clock(results[name], TIMING_KEYS) == without_clock(again, TIMING_KEYS)
