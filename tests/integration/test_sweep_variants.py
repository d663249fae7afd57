"""vrsim sweep's batched fast path for controller variants, end to end on a real LocalCluster: rows
equal the one-at-a-time sweep's to 1e-9 relative, and a controller that fails at run time is its own
failed row."""

import json
import math
import os
import shutil
import subprocess

import pytest

from tests.conftest import ROOT, VRSIM
from tests.integration.test_sweep import SCENARIO
from vrsim.services.outputs.sweep_results import _read_rows
from vrsim.services.sim.sweep import load_sweep, plan, run_group, variant_groups

SWEEP = """
scenarios = ["q.toml"]
seeds = [1, 2]
[axes]
"controller.kp" = [0.4, 0.8]
"controller.ki" = [1.0, 3.0]
"""
USER_SCENARIO = SCENARIO.split("[controller]")[0] + """
[controller]
kind = "python"
file = "my_controller.py"
[output]
plots = false
html = false
"""
USER_SWEEP = """
scenarios = ["u.toml"]
[axes]
"controller.class" = ["MyController", "NoSuchController"]
"""
TIMING = {"wall_time_s", "realtime_factor", "wall_s", "outputs_wall_s"}  # the machine, not the run


def sweep(folder, name, out, *args):
    p = subprocess.run([VRSIM, "sweep", str(folder / name), "--no-dashboard", "--json", "--quiet",
                        "--workers", "2", "--out", str(out), *args],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout), _read_rows(str(out / "results.parquet"))


def assert_same_figures(row: dict, want: dict) -> None:
    """Every column of `want` but the timing equals `row`'s, floats to 1e-9 relative."""
    for key, value in want.items():
        if key in TIMING:
            continue
        if isinstance(value, float) and not math.isnan(value):
            assert row[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        else:
            assert row[key] == value, key


def test_fast_path_rows_equal_one_at_a_time_rows(tmp_path):
    (tmp_path / "q.toml").write_text(SCENARIO)
    (tmp_path / "s.toml").write_text(SWEEP)
    outcome, fast = sweep(tmp_path, "s.toml", tmp_path / "fast")
    # --run-outputs needs each run's own result, so it takes the one-at-a-time path
    _, slow = sweep(tmp_path, "s.toml", tmp_path / "slow", "--run-outputs")
    assert (outcome["planned"], outcome["ok"], outcome["failed"]) == (8, 8, 0)
    slow_by_key = {r["key"]: r for r in slow}
    assert set(slow_by_key) == {r["key"] for r in fast}
    for row in fast:
        want = slow_by_key[row["key"]]
        assert [k for k in want if k != "outputs_wall_s"] == list(row)
        assert_same_figures(row, want)
    assert len({r["mae_kg_ha"] for r in fast}) == 8


def test_a_split_group_gives_the_rows_of_the_whole_group(tmp_path):
    """A group of variants cut into parts (one task each, each with its own drive) gives the rows of
    the whole group, to 1e-9 relative (in process, real SUMO)."""
    (tmp_path / "q.toml").write_text(SCENARIO)
    (tmp_path / "s.toml").write_text(SWEEP)
    whole = variant_groups(plan(load_sweep(str(tmp_path / "s.toml"))))[0]
    parts = variant_groups(whole, workers=2, min_part=2)
    assert [len(p) for p in parts] == [2, 2]
    split = [row for part in parts for row in run_group(part)]
    rows = run_group(whole)
    assert [r["key"] for r in split] == [r["key"] for r in rows] == [s.key for s in whole]
    for got, want in zip(split, rows, strict=True):
        assert got.keys() == want.keys() and want["status"] == "ok"
        assert_same_figures(got, want)
    assert len({r["mae_kg_ha"] for r in rows}) == 4


def test_a_variant_that_fails_at_run_time_is_its_own_failed_row(tmp_path):
    (tmp_path / "u.toml").write_text(USER_SCENARIO)
    (tmp_path / "s.toml").write_text(USER_SWEEP)
    shutil.copy(os.path.join(ROOT, "scenarios", "my_controller.py"), tmp_path / "my_controller.py")
    outcome, rows = sweep(tmp_path, "s.toml", tmp_path / "out")
    assert (outcome["planned"], outcome["ok"], outcome["failed"]) == (2, 1, 1)
    failed = next(r for r in rows if r["status"] == "failed")
    assert failed["controller.class"] == "NoSuchController" and "NoSuchController" in failed["error"]
