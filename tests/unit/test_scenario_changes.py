"""Changing a loaded scenario in code (`with_changes`): checked as a scenario file would be."""

import dataclasses

import pytest

from vrsim.common import ScenarioError
from vrsim.services.sim.scenario import load, with_changes


def test_with_changes_changes_only_what_it_names():
    sc = load("default")
    new = with_changes(sc, seed=3, implement={"width_m": 18.0}, controller={"gains": "textbook"})
    assert (new.seed, new.implement.width_m, new.controller.gains) == (3, 18.0, "textbook")
    assert new.implement == dataclasses.replace(sc.implement, width_m=18.0)  # the rest kept
    assert (sc.seed, sc.implement.width_m) == (1, 12.0)  # the original is untouched
    assert new.field == sc.field and new.map == sc.map


@pytest.mark.parametrize("changes, message", [
    (dict(implement={"width_m": -1.0}), "[implement] Implement: width_m must be a number > 0, got -1.0"),
    (dict(implement={"wdth_m": 1.0}), "[implement] unknown key 'wdth_m'"),
    (dict(tractor={"working_speed_m_s": "fast"}), "[tractor] working_speed_m_s must be number, got 'fast'"),
    (dict(field={"turn_radius_m": 0.0}), "[field] turn_radius_m must be > 0, got 0.0"),
    (dict(map={"policy": "sometimes"}), "[map] policy must be one of"),
    (dict(timing={"plant_step_s": 0.003}), "must be a whole multiple of plant_step_s"),
    (dict(plant={"transmission_ratio": 0.3}), "[plant] transmission_ratio: set it in [implement]"),
    (dict(seed=-1), "seed must be in [0, 2147483647], got -1"),
    (dict(seed=1.5), "seed must be int, got 1.5"),
    (dict(implement=18.0), "[implement] changes must be a dict"),
    (dict(wheels=4), "unknown key 'wheels'"),
])
def test_with_changes_refuses_what_a_file_may_not_say(changes, message):
    with pytest.raises(ScenarioError) as err:
        with_changes(load("default"), **changes)
    assert str(err.value).startswith("builtin:default: ") and message in str(err.value)
