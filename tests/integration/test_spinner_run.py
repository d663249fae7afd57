"""The ``spinner`` machine kind on real SUMO runs of the accuracy library's spinner scenarios (issue #25):

- at its nominal width (a triangle twice the driving width) the interior lies within +-10 % almost
  everywhere; at 1.5 x the interior's CV on the raster is the overlapped triangles' (14.3 %); driven
  too wide (1.2 x) it stripes: worse MAE, a CV on the raster two times higher and more;
- border spreading keeps the product inside the field (off-target product drops);
- the error split's spread-pattern part is what the pattern costs against strips;
- sweeps' batched variants give `control_and_account`'s summaries;
- bad machine input exits 2 with one line.
"""

import os
import subprocess

import numpy as np
import pytest

from tests.conftest import VRSIM
from tests.integration.test_machines_run import LIBRARY
from vrsim.controller import ControllerConfig
from vrsim.services.sim.error_split import CAUSES, error_split
from vrsim.services.sim.run import control_and_account, drive, run
from vrsim.services.sim.scenario import load, with_changes
from vrsim.services.sim.variants import run_variants

INTERIOR_MARGIN_M = 50.0   # the headland pass, the spread's reach and the throw kept out
HAND_CV_PCT = np.sqrt(31 / 54 - 9 / 16) / 0.75 * 100   # triangles 1.5 x the driving width


def _scenario(name: str, **implement):
    sc = load(os.path.join(LIBRARY, name + ".toml"))
    return with_changes(sc, implement=implement) if implement else sc


def _interior(result) -> tuple[np.ndarray, np.ndarray]:
    """The applied and the prescribed rate (kg/ha) of the cells at least `INTERIOR_MARGIN_M` inside
    the field: straight passes only."""
    import shapely

    grid = result.world.grid
    x, y = grid.cell_centres()
    xx, yy = np.meshgrid(x, y)
    inner = result.world.field.polygon.buffer(-INTERIOR_MARGIN_M)
    cells = shapely.contains_xy(inner, xx, yy)
    return result.as_applied.applied_kg_ha[cells], grid.rates_kg_ha[cells]


def _within_10_pct(applied, prescribed) -> float:
    return float(np.mean(np.abs(applied - prescribed) <= 0.1 * prescribed) * 100)


def _cv_pct(applied) -> float:
    return float(np.std(applied, ddof=1) / np.mean(applied) * 100)


@pytest.fixture(scope="module")
def runs():
    names = ("spinner_48m_at_24m", "spinner_36m_at_24m", "spinner_36m_at_30m",
             "spinner_36m_at_24m_no_border")
    return {name: run(_scenario(name)) for name in names}


def test_at_its_nominal_width_the_interior_is_within_10_pct_and_too_wide_stripes(runs):
    nominal, limit, wide = (runs[f"spinner_{n}"] for n in ("48m_at_24m", "36m_at_24m", "36m_at_30m"))
    assert _within_10_pct(*_interior(nominal)) >= 95.0
    assert nominal.summary["cv_pct"] == pytest.approx(0.0, abs=0.01)
    # The raster's interior CV is the overlapped pattern's (2 m cells blur it a little).
    assert _cv_pct(_interior(limit)[0]) == pytest.approx(HAND_CV_PCT, abs=2.0)
    assert limit.summary["cv_pct"] == pytest.approx(HAND_CV_PCT, abs=0.5)
    assert wide.summary["cv_pct"] > 2 * limit.summary["cv_pct"]
    assert _cv_pct(_interior(wide)[0]) > 2 * _cv_pct(_interior(limit)[0])
    assert wide.summary["mae_kg_ha"] > 1.5 * limit.summary["mae_kg_ha"] > 1.5 * nominal.summary["mae_kg_ha"]



def test_a_spinner_driven_beyond_cv_15_pct_is_warned_with_the_width_that_meets_it(runs):
    """Above EN 13739's 15 % the summary and the report warn and name the driving width that meets it
    (the pattern's effective width: the triangle 36 m wide meets it at 24 m, its CV there 14.3 %)."""
    from vrsim.services.outputs.summary import text_summary, warnings

    limit, wide = runs["spinner_36m_at_24m"], runs["spinner_36m_at_30m"]
    assert warnings(limit.summary) == []
    assert 24.0 < wide.summary["effective_width_m"] < 25.0, wide.summary["effective_width_m"]
    warned = warnings(wide.summary)
    assert len(warned) == 1 and f"{wide.summary['cv_pct']:.1f} %" in warned[0], warned
    assert f"drive at {wide.summary['effective_width_m']:,.2f} m or narrower" in warned[0], warned
    assert text_summary(wide.summary).endswith(warned[0])



def test_overlap_is_product_beyond_the_patterns_design(runs):
    """A spinner's throw reaches into its neighbours' driving width by design: the throw's raster
    overlaps on most of the field, the overlap figures (read on the driving width each pass owns,
    `Machine.ownership`) only where passes' own ground meets (headlands, pass ends)."""
    for name in ("spinner_36m_at_24m", "spinner_48m_at_24m"):
        result = runs[name]
        field = result.in_field
        covered = field & (result.as_applied.coverage_fraction >= 0.9)
        thrown_pct = 100.0 * result.as_applied.overlap_fraction[field].sum() / covered.sum()
        assert thrown_pct > 40.0, (name, thrown_pct)
        assert 0.0 < result.summary["overlap_area_pct"] < 10.0, (name, result.summary["overlap_area_pct"])

@pytest.mark.parametrize("path", [os.path.join(LIBRARY, "rectangle_uniform_ideal.toml"),
                                  os.path.join(os.path.dirname(LIBRARY), "..", "..", "scenarios",
                                               "sprayer.toml")], ids=["gated_meter", "sprayer"])
def test_a_kind_without_a_spread_pattern_has_no_spread_cv(path):
    """Strips side by side (a gated meter, a sprayer's boom) have no spread pattern: the CV and the
    effective width are null in the JSON and n/a in the text, never a flattering 0 %."""
    import json

    from vrsim.services.outputs.summary import summary_json, text_summary

    result = run(load(path))
    data = json.loads(summary_json(result.summary))
    assert data["cv_pct"] is None and data["effective_width_m"] is None
    line = next(line for line in text_summary(result.summary).splitlines() if "Spread CV" in line)
    assert "n/a" in line and "0.00" not in line

def test_border_spreading_keeps_the_product_inside_the_field(runs):
    on, off = runs["spinner_36m_at_24m"].summary, runs["spinner_36m_at_24m_no_border"].summary
    assert off["off_target_kg"] > 5.0 and on["off_target_kg"] < 0.05 * off["off_target_kg"]
    # The cut side meters only what lands inside: the same ground gets less than the uncut pattern.
    assert on["applied_kg"] < off["applied_kg"]


def test_each_disc_meters_half_and_the_mass_balances(runs):
    result = runs["spinner_36m_at_24m"]
    drive_kg = result.control["drive_kg"]
    assert drive_kg.shape[1] == 2
    np.testing.assert_allclose(drive_kg.sum(axis=1), result.control["metered_kg"])
    # What is metered lands: in the field or outside it, nothing lost.
    landed = result.as_applied.applied_kg_ha.sum() * result.world.grid.cell_area_m2 / 10_000
    assert landed + result.as_applied.outside_kg == pytest.approx(drive_kg.sum(), rel=1e-9)
    on = drive_kg > 0
    assert on[:, 0].mean() > 0.8 and on[:, 1].mean() > 0.8   # both discs work; sides switch apart


def test_the_error_split_names_what_the_pattern_costs(runs):
    for name in ("spinner_36m_at_24m", "spinner_36m_at_30m"):
        result = runs[name]
        parts = {p.cause: p for p in error_split(result)}
        assert list(parts) == list(CAUSES)
        assert sum(p.mae_kg_ha for p in parts.values()) == pytest.approx(result.summary["mae_kg_ha"],
                                                                          abs=1e-9)
        assert sum(p.mass_balance_pct for p in parts.values()) == pytest.approx(
            result.summary["mass_balance_pct"], abs=1e-9)
        assert parts["spread pattern"].mae_kg_ha > 10.0   # the pattern's stripes against strips
        assert abs(parts["metering"].mae_kg_ha) < 1e-6    # the ideal meter meters its targets exactly
    wide = error_split(runs["spinner_36m_at_30m"])[CAUSES.index("spread pattern")]
    limit = error_split(runs["spinner_36m_at_24m"])[CAUSES.index("spread pattern")]
    assert wide.mae_kg_ha > limit.mae_kg_ha


def test_batched_variants_give_the_runs_summaries():
    sc = _scenario("spinner_36m_at_24m", border_spreading=False)
    d = drive(sc)
    cfgs = [ControllerConfig(kind="PID"), ControllerConfig(kind="PI"), ControllerConfig(kind="ideal")]
    batched = run_variants(d, cfgs)
    for cfg, summary in zip(cfgs, batched, strict=True):
        alone = control_and_account(d, cfg).summary
        for key, value in alone.items():
            if key in ("wall_time_s", "realtime_factor", "stage_s"):
                continue
            if isinstance(value, (float, dict)):   # a dict: the figures in the map's own unit
                assert summary[key] == pytest.approx(value, rel=1e-9, abs=1e-9, nan_ok=True), key
            else:
                assert summary[key] == value, key


@pytest.mark.parametrize("change, message", [
    ("implement.spread_width_m=20", "[implement] SpinnerSpec: spread_width_m=20 must be at least the driving "
                                    "width width_m=24"),
    ("implement.sections=3", "[implement] Implement: kind 'spinner' supports at most 2 sections, got "
                             "sections=3"),
    ("implement.turn_compensation=true", "[implement] turn_compensation is a key of kind 'section_drives', "
                                         "not of kind 'spinner'"),
    ("implement.pattern=missing.csv", "[implement] pattern "),
])
def test_bad_machine_input_exits_2_with_one_line(tmp_path, change, message):
    path = os.path.join(LIBRARY, "spinner_36m_at_24m.toml")
    p = subprocess.run([VRSIM, "run", path, "--set", change, "--quiet", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    assert p.stderr.count("\n") == 1 and message in p.stderr and "Traceback" not in p.stderr, p.stderr


def test_the_streamed_run_gives_the_in_process_runs_figures():
    from vrsim.services.sim.streamed import run_streamed

    sc = with_changes(_scenario("spinner_36m_at_24m"), controller={"kind": "PID"})
    whole, parts = run(sc).summary, run_streamed(sc, ticks_per_part=3000).summary
    for key, value in whole.items():
        if isinstance(value, float) and key not in ("wall_time_s", "realtime_factor"):
            assert parts[key] == pytest.approx(value, rel=1e-9, abs=1e-9, nan_ok=True), key
