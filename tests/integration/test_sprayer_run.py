"""The sprayer kind on real SUMO runs (issue #26): per-nozzle PWM turn compensation levels the inner and
the outer section of a 20 m-radius turn with a 12 m boom; one valve (flow control) leaves the geometric
ratio (25 / 15: the outer section's radius over the inner's)."""

import os

import pytest

from services.sim.run import run
from services.sim.scenario import load, with_changes
from tests.integration.test_machines_run import turn_rates_kg_ha

LIBRARY = os.path.join(os.path.dirname(os.path.dirname(__file__)), "accuracy", "scenarios")


def test_pwm_turn_compensation_levels_a_20_m_turn_and_one_valve_follows_the_geometry():
    sc = load(os.path.join(LIBRARY, "tight_turn_sprayer_pwm.toml"))
    inner, outer = turn_rates_kg_ha(run(sc))
    assert inner / outer == pytest.approx(1.0, abs=0.05)
    assert inner == pytest.approx(200, rel=0.05) and outer == pytest.approx(200, rel=0.05)
    inner, outer = turn_rates_kg_ha(run(with_changes(sc, implement={"control": "flow"})))
    assert inner / outer == pytest.approx(25 / 15, rel=0.05)
