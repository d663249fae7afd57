"""The sprayer kind on real SUMO runs (issue #26): per-nozzle PWM turn compensation levels the inner and
the outer section of a 20 m-radius turn with a 12 m boom; one valve (flow control) leaves the geometric
ratio (25 / 15: the outer section's radius over the inner's)."""

import os

import pytest

from tests.integration.test_machines_run import LIBRARY, turn_rates_kg_ha
from vrsim.services.sim.run import run
from vrsim.services.sim.scenario import load, with_changes


def test_pwm_turn_compensation_levels_a_20_m_turn_and_one_valve_follows_the_geometry():
    sc = load(os.path.join(LIBRARY, "tight_turn_sprayer_pwm.toml"))
    inner, outer = turn_rates_kg_ha(run(sc))
    assert inner / outer == pytest.approx(1.0, abs=0.05)
    assert inner == pytest.approx(200, rel=0.05) and outer == pytest.approx(200, rel=0.05)
    inner, outer = turn_rates_kg_ha(run(with_changes(sc, implement={"control": "flow"})))
    assert inner / outer == pytest.approx(25 / 15, rel=0.05)


def test_uan_under_flow_control_follows_its_map_within_the_nozzles_flows_of_it():
    """sprayer_l_ha_geotiff: UAN 28 % (1.28 kg/L) through 04 nozzles at 1-5 bar under flow control. A nozzle
    passes sqrt(1 / 1.28) of its water rating at a pressure (`vehicle.sprayer.density_flow_factor`): the
    run's machine check has the flows and speeds of water times 0.884, and the loop, its plant the boom's
    orifice for UAN, applies the map (140-220 L/ha) in its own unit."""
    import math

    from vrsim.vehicle.sprayer import SprayerSpec

    result = run(load(os.path.join(LIBRARY, "sprayer_l_ha_geotiff.toml")))
    f = math.sqrt(1 / 1.28)
    water = SprayerSpec(nozzle="04", pressure_range_bar=(1.0, 5.0))
    check = result.machine_check
    q_lo, q_hi = water.nozzle_flow_range_l_min()
    assert (check.nozzle_flow_min_l_min, check.nozzle_flow_max_l_min) == pytest.approx((q_lo * f, q_hi * f))
    lo_l, hi_l = check.rate_min_kg_ha / 1.28, check.rate_max_kg_ha / 1.28
    v_lo, v_hi = water.speed_range_m_s(lo_l, hi_l)
    assert (check.min_speed_m_s, check.max_speed_m_s) == pytest.approx((v_lo * f, v_hi * f))
    assert check.can_apply and check.nozzle_suggested == "05"
    summary = result.summary
    assert summary["rate_unit"] == "L/ha" and abs(summary["mass_balance_pct"]) < 2.0
    assert summary["in_rate_unit"]["mae"] < 0.05 * lo_l and summary["within_10pct_area_pct"] > 90.0


SPRAYER_FIELD = """
name = "sprayer_variants"
seed = 4
[field]
rectangle = { width_m = 60.0, length_m = 120.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "uniform"
cell_size_m = 2.0
params = { rate_kg_ha = 200.0 }
[implement]
width_m = 12.0
sections = 4
kind = "sprayer"
nozzle = "05"
control = "CONTROL"
flow_meter_error_pct = 3.0
[product]
form = "liquid"
density_kg_l = 1.1
"""


@pytest.mark.parametrize("control", ["flow", "pwm"])
def test_batched_variants_of_a_sprayer_equal_its_one_at_a_time_runs(control):
    """Sweeps' batched variants run the sprayer's flow loops (its plant, not the shaft's): each summary
    equals control_and_account's."""
    from tests.integration.test_variants import assert_same_summary
    from vrsim.controller import ControllerConfig
    from vrsim.services.sim import scenario
    from vrsim.services.sim.run import control_and_account, drive
    from vrsim.services.sim.variants import run_variants

    shared = drive(scenario.parse(SPRAYER_FIELD.replace("CONTROL", control), "sprayer.toml", "."))
    cfgs = [ControllerConfig(kind="PID"), ControllerConfig(kind="PID", gains="manual", kp=0.2, ki=0.5),
            ControllerConfig(kind="PID", look_ahead_s="auto"), ControllerConfig(kind="ideal")]
    for fast, cfg in zip(run_variants(shared, cfgs), cfgs, strict=True):
        assert_same_summary(fast, control_and_account(shared, cfg).summary)


def test_calibrating_the_flow_meter_brings_the_mass_balance_back_within_one_percent(tmp_path):
    """A flow meter reading 5 % high under-applies about 4.8 %; `vrsim calibrate`'s catch test prints the
    constant (and the error the same meter has left); the next run with them is within 1 %."""
    import json
    import subprocess

    from tests.conftest import VRSIM

    path = os.path.join(LIBRARY, "sprayer_meter_error_5pct.toml")

    def vrsim(*args):
        p = subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr
        return p.stdout

    def mass_balance_pct(*sets):
        out = vrsim("run", path, "--quiet", "--json", "--out", str(tmp_path / "run"),
                    *(a for s in sets for a in ("--set", s)))
        return json.loads(out)["mass_balance_pct"]

    assert mass_balance_pct() == pytest.approx(100 * (1 / 1.05 - 1), abs=1.0)
    text = vrsim("calibrate", path)
    assert "Put in the scenario: [implement] flow_meter_pulses_per_l = " in text
    settings = json.loads(vrsim("calibrate", path, "--json"))["settings"]
    assert settings["implement.flow_meter_pulses_per_l"] == pytest.approx(630.0, rel=0.005)
    assert abs(mass_balance_pct(*(f"{k}={v}" for k, v in settings.items()))) < 1.0


def test_the_error_split_puts_a_flow_meters_error_under_calibration():
    """The reference meters run in the sprayer's terms (L/min, litres x density): a meter reading 5 % high
    is the calibration part (about 1 - 1/1.05), the nozzles in range leave the machine limits near 0."""
    from vrsim.services.sim.error_split import error_split

    result = run(load(os.path.join(LIBRARY, "sprayer_meter_error_5pct.toml")))
    parts = {p.cause: p for p in error_split(result)}
    assert parts["calibration"].mass_balance_pct == pytest.approx(100 * (1 / 1.05 - 1), abs=0.5)
    assert abs(parts["machine limits"].mass_balance_pct) < 1.0
    assert abs(parts["metering"].mass_balance_pct) < 1.0


def _vrsim(*args):
    import subprocess

    from tests.conftest import VRSIM

    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=300)


def test_bad_sprayer_input_is_one_line_naming_file_key_and_value(tmp_path):
    path = os.path.join(LIBRARY, "sprayer_default_field.toml")
    p = _vrsim("run", path, "--check", "--set", "implement.pressure_range_bar=[1.5, 5.0]")
    assert p.returncode == 2 and p.stderr.count("\n") == 1
    assert f"{path}: [implement] sprayer: nozzle '04'" in p.stderr and "at any speed" in p.stderr
    p = _vrsim("run", path, "--check")
    assert p.returncode == 0 and "the sprayer can apply the map" in p.stdout
    small = os.path.join(LIBRARY, "sprayer_meter_error_5pct.toml")
    for change, says in (("product.form=granular", "[product] form: a sprayer meters a liquid, got 'gran"),
                         ("product.calibration_error_pct=3", "[product] calibration_error_pct: a sprayer's"),
                         ("implement.sections=5", "[implement] section_widths_m: section 3 (2.4 m)")):
        p = _vrsim("run", small, "--quiet", "--out", str(tmp_path / "bad"), "--set", change)
        assert p.returncode == 2 and p.stderr.count("\n") == 1 and f"{small}: {says}" in p.stderr, p.stderr
    # The machine check alone (no loop built) says a boom its nozzles do not fit as the run does.
    p = _vrsim("run", small, "--check", "--set", "implement.sections=5")
    assert p.returncode == 2 and p.stderr.count("\n") == 1, p.stderr
    assert f"{small}: [implement] section_widths_m: section 3 (2.4 m)" in p.stderr, p.stderr
    for args, says in ((("--set", "product.form=granular"), "[product] form 'granular': a sprayer meters"),
                       (("--seconds", "0"), "--seconds 0.0: must be"),
                       (("--jug-error-ml", "-1"), "--jug-error-ml -1.0: must be")):
        p = _vrsim("calibrate", small, *args)
        assert p.returncode == 2 and p.stderr.count("\n") == 1 and says in p.stderr, p.stderr


def test_vrsim_runs_streamed_parts_give_the_in_process_runs_figures(tmp_path):
    """`vrsim run` (its streamed parts, SUMO in a second process) of the PWM example equals the in-process
    run: the sections' flow loops carry their state from part to part."""
    import json

    from tests.conftest import ROOT

    path = os.path.join(ROOT, "scenarios", "sprayer.toml")
    p = _vrsim("run", path, "--quiet", "--json", "--out", str(tmp_path / "out"),
               "--set", "output.plots=false", "--set", "output.html=false")
    assert p.returncode == 0, p.stderr
    streamed, in_process = json.loads(p.stdout), run(load(path)).summary
    for key in ("applied_kg", "mass_balance_pct", "mae_kg_ha", "within_10pct_area_pct", "limited_time_pct"):
        assert streamed[key] == pytest.approx(in_process[key], rel=1e-12), key
