"""The batched fast path for controller variants: one drive, many controllers at once, each equal to its
one-at-a-time run (real SUMO on a small field)."""

import dataclasses
import math

import pytest

from vrsim.controller import ControllerConfig
from vrsim.services.sim import scenario
from vrsim.services.sim.run import control_and_account, drive
from vrsim.services.sim.variants import run_variants

FIELD = """
name = "variants"
seed = 4
[field]
rectangle = { width_m = 60.0, length_m = 120.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "zones"
cell_size_m = 2.0
params = { n_zones = 5 }
[implement]
width_m = 12.0
sections = 4
"""
TIMINGS = ("wall_time_s", "realtime_factor", "stage_s")


@pytest.fixture(scope="module")
def shared_drive():
    return drive(scenario.parse(FIELD, "variants.toml", "."))


def assert_same_summary(fast: dict, slow: dict, rel: float = 1e-9) -> None:
    assert fast.keys() == slow.keys()
    for key, want in slow.items():
        if key in TIMINGS:
            continue
        got = fast[key]
        if isinstance(want, float) and math.isnan(want):
            assert math.isnan(got), key
        elif isinstance(want, (int, float)):
            assert got == pytest.approx(want, rel=rel, abs=1e-12), key
        elif isinstance(want, dict):  # in_rate_unit: figures again, in the map's unit
            assert_same_summary(got, want, rel)
        else:
            assert got == want, key


def test_variants_equal_one_at_a_time_runs(shared_drive):
    """PID gains per loop on the fast path (both forms, derivative on measurement), other kinds on the
    shared drive one after another, a fixed and an automatic look-ahead (separate batches) and the
    look-ahead tune (alone): every summary equals control_and_account's to 1e-9 relative."""
    cfgs = [ControllerConfig(kind="PID", gains="manual", kp=kp, ki=ki, kd=kd)
            for kp, ki, kd in ((0.2, 0.5, 0.0), (0.573, 3.7, 0.01), (1.5, 8.0, 0.02))]
    cfgs += [ControllerConfig(kind="PID"), ControllerConfig(kind="PI", form="positional"),
             ControllerConfig(kind="PID", gains="textbook", derivative_on_measurement=True),
             ControllerConfig(kind="PID", look_ahead_s="auto"),
             ControllerConfig(kind="PID", look_ahead_s=0.2), ControllerConfig(kind="aog_pi"),
             ControllerConfig(kind="ideal"), ControllerConfig(kind="fuzzy_pid"),
             ControllerConfig(kind="PID", look_ahead_tune=0.5)]
    fast = run_variants(shared_drive, cfgs)
    assert len(fast) == len(cfgs)
    for cfg, summary in zip(cfgs, fast, strict=True):
        assert_same_summary(summary, control_and_account(shared_drive, cfg).summary)
    assert len({round(s["mae_kg_ha"], 9) for s in fast}) > 5   # the variants do differ
    stage = fast[0]["stage_s"]
    assert fast[0]["wall_time_s"] == pytest.approx(sum(stage.values()))
    assert {"build_s", "sumo_s", "sensors_s", "control_s", "metrics_s"} <= stage.keys()


def test_variants_with_a_limited_machine_and_overlap_equal_one_at_a_time_runs():
    """Per-section landing on the fast path: a shaft too slow for the map (machine-limited ticks and
    area) and passes that overlap; every figure, the overlap and limit ones too, equals
    control_and_account's to 1e-9 relative."""
    limited = drive(scenario.parse(FIELD + "shaft_rpm_max = 60.0\n", "limited.toml", "."))
    cfgs = [ControllerConfig(kind="PID"), ControllerConfig(kind="PI", form="positional"),
            ControllerConfig(kind="ideal")]
    fast = run_variants(limited, cfgs)
    for cfg, summary in zip(cfgs, fast, strict=True):
        assert_same_summary(summary, control_and_account(limited, cfg).summary)
    assert all(s["limited_time_pct"] > 0 and s["limited_area_pct"] > 0 for s in fast)
    assert all(s["overlap_kg"] > 0 and s["overlap_area_pct"] > 0 and s["sections"] == 4 for s in fast)


def test_variants_of_a_product_with_uneven_flow_equal_one_at_a_time_runs():
    """A product whose flow varies revolution to revolution, 4 % off its configured constant: each
    variant's shaft starts at rest as a run's does, also for PID loops batched in columns, so every
    summary equals control_and_account's."""
    uneven = drive(scenario.parse(FIELD + "[product]\nflow_cv_pct = 10.0\ncalibration_error_pct = -4.0\n",
                                  "uneven.toml", "."))
    cfgs = [ControllerConfig(kind="PID", gains="manual", kp=kp, ki=ki, kd=0.0) for kp, ki in ((0.2, 0.5),
                                                                                            (0.573, 3.7))]
    cfgs += [ControllerConfig(kind="PID"), ControllerConfig(kind="ideal")]
    fast = run_variants(uneven, cfgs)
    for cfg, summary in zip(cfgs, fast, strict=True):
        assert_same_summary(summary, control_and_account(uneven, cfg).summary)
    assert all(s["mass_balance_pct"] < -2 for s in fast)


def test_a_bad_variant_is_a_scenario_error(shared_drive, tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("raise RuntimeError('no')\n")
    cfg = ControllerConfig(kind="python", file=str(bad), class_name="Nope")
    with pytest.raises(scenario.ScenarioError, match="controller"):
        run_variants(shared_drive, [ControllerConfig(kind="PID"), cfg])


def test_variants_of_a_drive_per_section_equal_one_at_a_time_runs(shared_drive):
    """``section_drives``: a loop per variant and section in one batch, each section's strips from its
    own drive's mass columns (`maps.ColumnDeposit`); every summary equals control_and_account's."""
    world = shared_drive.world
    sc = scenario.with_changes(world.scenario, implement={"kind": "section_drives"})
    per_section = dataclasses.replace(shared_drive, world=dataclasses.replace(world, scenario=sc))
    cfgs = [ControllerConfig(kind="PID"), ControllerConfig(kind="PID", gains="textbook"),
            ControllerConfig(kind="aog_pi"), ControllerConfig(kind="ideal")]
    fast = run_variants(per_section, cfgs)
    for cfg, got in zip(cfgs, fast, strict=True):
        assert_same_summary(got, control_and_account(per_section, cfg).summary)
    gated = run_variants(shared_drive, cfgs[-1:])[0]
    assert fast[-1]["mae_kg_ha"] < gated["mae_kg_ha"]   # the zones' edges cut sections, not the boom


def test_variants_of_a_machine_with_a_fitted_response_equal_one_at_a_time_runs():
    """A machine's [response] (dead time in the loop, pass-start preset, opening transient, offset):
    the batched variants meter through the same opening factor and preset targets, so every summary
    equals control_and_account's, and the response moves the figures."""
    response = ("[response]\ndead_time_s = 0.6\nstartup_speed_m_s = 4.0\nstartup_hold_s = 2.0\n"
                "opening_peak_pct = 60.0\nopening_time_constant_s = 1.5\ncalibration_error_pct = 2.0\n")
    twin = drive(scenario.parse(FIELD + response, "twin.toml", "."))
    cfgs = [ControllerConfig(kind="PID", gains="manual", kp=kp, ki=ki, kd=0.0) for kp, ki in ((0.2, 0.5),
                                                                                            (0.573, 3.7))]
    cfgs += [ControllerConfig(kind="PID"), ControllerConfig(kind="ideal")]
    fast = run_variants(twin, cfgs)
    for cfg, summary in zip(cfgs, fast, strict=True):
        assert_same_summary(summary, control_and_account(twin, cfg).summary)
    plain = run_variants(drive(scenario.parse(FIELD, "variants.toml", ".")), cfgs[2:3])[0]
    assert fast[2]["mass_balance_pct"] > plain["mass_balance_pct"] + 1.5   # the offset and the openings
