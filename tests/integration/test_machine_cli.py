"""`vrsim machine pattern` through the real executable: a spinner's catch-tray test (CV, effective width,
pattern.png) on scenarios/spinner.toml and on a measured profile, and bad input (exit 2, one line)."""

import json
import math
import os
import subprocess

import pytest

from tests.conftest import ROOT, VRSIM

SPINNER = os.path.join(ROOT, "scenarios", "spinner.toml")
# Triangles 1.5 x the driving width, overlapped (tests/unit/test_spinner.py derives it by hand).
HAND_CV_PCT = math.sqrt(31 / 54 - 9 / 16) / 0.75 * 100


def vrsim(*args):
    return subprocess.run([VRSIM, "machine", *map(str, args)], capture_output=True, text=True, timeout=120)


def scenario(tmp_path, implement: str, name="s.toml"):
    """A scenario file whose [implement] table is `implement` (TOML lines): the scenario is loaded and
    checked whole, so it has a field and a map."""
    path = tmp_path / name
    path.write_text(f'name = "t"\n[field]\nrectangle = {{ width_m = 100.0, length_m = 100.0, lat = 52.1, '
                    f'lon = 10.5 }}\n[map]\nsynthetic = "uniform"\n[implement]\n{implement}\n')
    return path


SPIN = 'kind = "spinner"\nwidth_m = 24.0\nspread_width_m = 36.0\n'


def test_the_spinner_scenario_gives_the_hand_computed_cv_and_writes_the_profile(tmp_path):
    p = vrsim("pattern", SPINNER, "--out", tmp_path, "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["driving_width_m"] == 24.0 and out["spread_width_m"] == 36.0 and out["passes"] == 3
    assert out["cv_pct"] == pytest.approx(HAND_CV_PCT, abs=0.5)
    assert 24.0 < out["effective_width_m"] < 24.5 and out["cv_limit_pct"] == 15.0
    assert sum(out["trays"]["in_width"]) == 48
    png = tmp_path / "pattern.png"
    assert out["files"] == [str(png)] and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [f for f in os.listdir(tmp_path) if f != "pattern.png"] == []  # nothing partial left


def test_text_output_names_the_figures(tmp_path):
    p = vrsim("pattern", SPINNER, "--out", tmp_path / "new" / "folder")
    assert p.returncode == 0, p.stderr
    assert "CV  " in p.stdout and "effective width at CV 15 %" in p.stdout and "24.2" in p.stdout
    assert f"{HAND_CV_PCT:.1f}"[:3] in p.stdout and (tmp_path / "new" / "folder" / "pattern.png").exists()


def test_a_measured_profile_beside_the_scenario(tmp_path):
    (tmp_path / "tray.csv").write_text("offset_m,relative_mass\n" + "".join(
        f"{x},{1 - abs(x) / 18:.4f}\n" for x in range(-18, 19, 2)))
    path = scenario(tmp_path, SPIN + 'pattern = "tray.csv"\nthrow_distance_m = 0.0\n')
    p = vrsim("pattern", path, "--out", tmp_path, "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["pattern"] == str(tmp_path / "tray.csv")
    assert out["cv_pct"] == pytest.approx(HAND_CV_PCT, abs=0.5)


BAD = [
    (SPIN.replace("36.0", "20.0"), None, "[implement] SpinnerSpec: spread_width_m=20 must be at least the "
                                         "driving width width_m=24"),
    ('kind = "gated_meter"\nwidth_m = 24.0\n', None, '[implement] kind: machine pattern needs a spinner '
                                                     '(kind = "spinner"), got \'gated_meter\''),
    ('width_m = 24.0\n', None, "got 'gated_meter' (its strips lie side by side: no spread pattern"),
    (SPIN + "sections = 3\n", None, "[implement] Implement: kind 'spinner' supports at most 2 sections, got "
                                    "sections=3"),
    (SPIN + "turn_compensation = true\n", None, "[implement] turn_compensation is a key of kind "
                                                "'section_drives', not of kind 'spinner'"),
    (SPIN.replace("24.0", "-3.0"), None, "[implement] Implement: width_m must be a number > 0, got -3.0"),
    (SPIN + "side_steps = 0\n", None, "[implement] SpinnerSpec: side_steps must be an integer in [1, 16], "
                                       "got 0"),
    (SPIN + 'pattern = "round"\n', None, "pattern must be one of triangular, trapezoidal or a CSV"),
    (SPIN + 'pattern = "missing.csv"\n', None, "[implement] pattern "),
    (SPIN + 'pattern = "p.csv"\n', "", "p.csv: no rows"),
    (SPIN + 'pattern = "p.csv"\n', "-10,1\n0,-1\n10,1\n", "p.csv: row 2: relative mass -1 is negative"),
    (SPIN + 'pattern = "p.csv"\n', "-10,1\n5,1\n0,1\n", "p.csv: row 3: offset 0 m does not increase"),
    (SPIN + 'pattern = "p.csv"\n', "-10,1\n0,x\n10,1\n", "p.csv: row 2: 'x' is not a finite number"),
    (SPIN + 'pattern = "p.csv"\n', "-10,1\n10,1\n", "p.csv: 2 row(s): a profile needs at least 3"),
    (SPIN + 'pattern = "p.csv"\n', "-10,0\n0,0\n10,0\n", "p.csv: every relative mass is zero"),
    (SPIN + 'pattern = "p.csv"\n', "-10,1\n0,1\n19,1\n", "p.csv: row 3: offset 19 m lies beyond half the "
                                                          "spread"),
]


@pytest.mark.parametrize("implement, csv, message", BAD)
def test_bad_input_exits_2_with_one_line(tmp_path, implement, csv, message):
    if csv is not None:
        (tmp_path / "p.csv").write_text(csv)
    path = scenario(tmp_path, implement)
    p = vrsim("pattern", path, "--out", tmp_path)
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert p.stderr.startswith(f"vrsim machine: error: {path}: ") and p.stderr.count("\n") == 1, p.stderr
    assert message in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "pattern.png").exists()


def test_bad_files_and_options_exit_2(tmp_path):
    broken = tmp_path / "broken.toml"
    broken.write_text("[implement\n")
    for args, message in [(("pattern", tmp_path / "none.toml"), "no such scenario file"),
                          (("pattern", broken), "not valid TOML"),
                          (("pattern", SPINNER, "--tray-width", "0"), "tray width 0.0 m must be > 0"),
                          (("pattern", SPINNER, "--tray-width", "30"), "at most the driving width 24 m"),
                          (("plot", SPINNER), "invalid choice: 'plot'")]:
        p = vrsim(*args, "--out", tmp_path)
        assert p.returncode == 2 and message in p.stderr and "Traceback" not in p.stderr, (args, p.stderr)
    (tmp_path / "a_file").write_text("")
    p = vrsim("pattern", SPINNER, "--out", tmp_path / "a_file")
    assert p.returncode == 2 and "cannot create the folder" in p.stderr, p.stderr
    assert p.stderr.count("\n") == 1


def test_set_changes_the_scenario_as_for_run(tmp_path):
    p = vrsim("pattern", SPINNER, "--set", "implement.spread_width_m=30.0", "--out", tmp_path, "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["spread_width_m"] == 30.0 and out["cv_pct"] != pytest.approx(HAND_CV_PCT, abs=0.5)
    p = vrsim("pattern", SPINNER, "--set", "implement.spread_width_m=-1", "--out", tmp_path)
    assert p.returncode == 2 and "spread_width_m" in p.stderr and len(p.stderr.strip().splitlines()) == 1
