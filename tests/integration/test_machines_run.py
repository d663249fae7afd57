"""The machine kinds' goals on real SUMO runs of the accuracy library's scenarios (issue #25):

- zones whose edges run along the swaths (18 m implement at 3.6 m/s, ideal meter): a drive per
  section at least halves the gated meter's MAE (one rate across the whole width);
- headland corners turned at a 20 m radius with a 12 m implement on a uniform 200 kg/ha map: one
  meter puts ~267 kg/ha on the inner section and ~160 on the outer (200 x 20 / 15 and 200 x 20 / 25);
  a drive per section with turn compensation brings their ratio within 5 % of 1.
"""

import os

import numpy as np
import pytest

from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.run import run
from vrsim.services.sim.scenario import load, with_changes

LIBRARY = os.path.join(os.path.dirname(os.path.dirname(__file__)), "accuracy", "scenarios")
TURN_RADIUS_M = 20.0


def _run(name: str, **implement):
    sc = load(os.path.join(LIBRARY, name + ".toml"))
    return run(with_changes(sc, implement=implement) if implement else sc)


@pytest.fixture(scope="module")
def section_drives():
    """The tight-turn scenario with a drive per section as the library has it: one run for the tests
    that only read it."""
    return _run("tight_turn_section_drives")


def test_a_drive_per_section_at_least_halves_the_gated_meters_mae_on_zones_along_travel():
    gated = _run("zones_along_travel_gated_meter").summary
    per_section = _run("zones_along_travel_section_drives").summary
    assert per_section["mae_kg_ha"] <= 0.5 * gated["mae_kg_ha"]
    assert per_section["within_10pct_area_pct"] > gated["within_10pct_area_pct"]


def turn_rates_kg_ha(result, radius_m: float = TURN_RADIUS_M) -> tuple[float, float]:
    """The applied rate of the inner and the outer section over the steady parts of the turns worked
    at `radius_m` (the headland's corners), kg/ha: each section's product over its strip's area.

    A tick's product lands during [t + delay, t + delay + period]; a section at offset o (left
    positive) travels the centre's distance minus o times the heading's change meanwhile (summed over
    many ticks that is its arc; the lanes are polylines that turn in steps). Ticks count where the
    path's curvature over +-1 s lies within 0.75 to 1.33 times 1 / radius for 2 s either side and all
    gates are open.
    """
    sc, track, states = result.world.scenario, result.track, result.sections
    imp, period_s = sc.implement, sc.timing.control_period_s
    t, x, y = (np.asarray(track[k], float) for k in ("time_s", "x_m", "y_m"))
    heading = np.unwrap(np.asarray(track["heading_rad"], float))
    s_m = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    land = [np.interp(t + imp.delivery_delay_s + e, t, v) for e in (0.0, period_s) for v in (s_m, heading)]
    travel_m = (land[2] - land[0])[:, None] - (land[3] - land[1])[:, None] * imp.section_offsets_m
    kg = machine_for(imp).deposit_kg(result.control)
    if kg.ndim == 1:   # one meter: shared between the open sections by width
        width_on = np.maximum(states.actual @ states.widths_m, 1e-12)
        kg = np.where(states.actual, kg[:, None] * states.widths_m / width_on[:, None], 0.0)
    k = round(1.0 / period_s)
    idx = np.arange(t.size)
    a, b = np.clip(idx - k, 0, t.size - 1), np.clip(idx + k, 0, t.size - 1)
    curvature = (heading[b] - heading[a]) / np.maximum(s_m[b] - s_m[a], 1e-9)
    turning = ((np.abs(curvature) > 0.75 / radius_m) & (np.abs(curvature) < 1.33 / radius_m)
               & np.asarray(track["implement_on"], bool))
    steady = np.convolve(turning, np.ones(4 * k + 1), "same") >= 4 * k + 1
    at = np.clip(np.searchsorted(t, t + imp.delivery_delay_s), 0, t.size - 1)
    ticks = np.flatnonzero(steady[at] & states.actual.all(axis=1))
    assert ticks.size > 100, "no steady turn found"
    inner = np.where(curvature[at[ticks]] > 0, 0, imp.sections - 1)   # a left turn: the leftmost is inner
    outer = imp.sections - 1 - inner

    def rate(section):
        area_m2 = (states.widths_m[section] * travel_m[ticks, section]).sum()
        return float(kg[ticks, section].sum() / area_m2 * 1e4)

    return rate(inner), rate(outer)


def test_turn_compensation_levels_the_inner_and_outer_sections_of_a_20_m_turn(section_drives):
    inner, outer = turn_rates_kg_ha(_run("tight_turn_gated_meter"))
    assert inner == pytest.approx(200 * 20 / 15, rel=0.05) and outer == pytest.approx(200 * 20 / 25, rel=0.05)
    inner, outer = turn_rates_kg_ha(section_drives)
    assert inner / outer == pytest.approx(1.0, abs=0.05)
    assert inner == pytest.approx(200, rel=0.05) and outer == pytest.approx(200, rel=0.05)
    # Without turn compensation each drive runs at the centre's speed: the one meter's split again.
    inner, outer = turn_rates_kg_ha(_run("tight_turn_section_drives", turn_compensation=False))
    assert inner / outer == pytest.approx(25 / 15, rel=0.05)


def test_one_drive_on_its_speed_limit_flags_the_tick_where_the_machine_level_target_does_not(section_drives):
    """A 20 m-radius turn with turn compensation: the outer section's drive turns 1.3x the centre's
    speed. With the shaft's range just above the straight passes' need, the outer drive alone sits on
    its bound in the turns while the machine-level (combined) target does not: the tick counts as
    machine-limited, and `limited_time_pct` is the share of applying ticks with any drive on a bound."""
    straight = section_drives
    target = straight.control["target_shaft_rpm"]
    rpm_max = 1.1 * float(np.median(target[straight.accounts.setting.applying]))
    result = _run("tight_turn_section_drives", shaft_rpm_max=rpm_max)
    imp, control, setting = result.world.scenario.implement, result.control, result.accounts.setting
    on_bound = imp.shaft_limited(control["drive_target_rpm"]) & control["drive_open"]
    combined = imp.shaft_limited(control["target_shaft_rpm"]) & setting.applying
    np.testing.assert_array_equal(setting.limited, on_bound.any(axis=1) & setting.applying)
    alone = setting.limited & ~combined
    assert alone.sum() > 20 and (on_bound[alone].sum(axis=1) < imp.sections).all()
    assert result.summary["limited_time_pct"] == pytest.approx(
        100.0 * setting.limited.sum() / setting.applying.sum())
    assert result.summary["limited_area_pct"] > 0
