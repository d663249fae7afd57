"""`vrsim paper` through the real executable."""

import json
import os
import subprocess

import pytest

from tests.conftest import VRSIM


def _vrsim(*args, cwd=None):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def paper_json(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    p = _vrsim("paper", "--json", "--out", str(out))
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout), out


def test_json_shape_and_figure(paper_json):
    d, out = paper_json
    assert os.path.getsize(out / "step_responses.png") > 10_000
    assert {"Ku", "Tu_s", "paper_Ku", "paper_Tu_s"} <= set(d["ultimate"])
    for group in (d, d["textbook"]):
        for kind in ("P", "PI", "PID"):
            keys = {"overshoot_pct", "settling_s", "paper_overshoot_pct", "paper_settling_s"}
            assert keys <= set(group[kind])
    assert d["P"]["paper_overshoot_pct"] == 78.38 and d["PID"]["paper_settling_s"] == 1.7
    for name, a in d["assumptions"].items():
        assert set(a) == {"value", "unit", "why"} and a["why"], name


def test_ultimate_point_is_reproduced_and_the_rest_is_reported_honestly(paper_json):
    d, _ = paper_json
    assert d["ultimate"]["Ku"] == pytest.approx(0.955, rel=0.02)
    assert d["ultimate"]["Tu_s"] == pytest.approx(0.31, rel=0.02)
    # the paper's PID derivative is negligible: its PI and PID responses nearly coincide in vrsim
    assert d["PID"]["overshoot_pct"] == pytest.approx(d["PI"]["overshoot_pct"], rel=0.02)
    assert any("cannot come from its printed gains" in f for f in d["findings"])


def test_table_without_json_into_the_default_out_dir(tmp_path, paper_json):
    p = _vrsim("paper", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "paper vs vrsim" in p.stdout and "textbook Z-N PID" in p.stdout and "Findings:" in p.stdout
    assert (tmp_path / "runs" / "paper" / "step_responses.png").is_file()
    # each controller's loop margins, as --json gives them under "loop"
    margins = p.stdout.split("loop margins")[1].split("Findings:")[0]
    for label, group in (("paper gains", paper_json[0]), ("textbook Z-N", paper_json[0]["textbook"])):
        for kind in ("PI", "PID"):
            loop = group[kind]["loop"]
            row = next(line for line in margins.splitlines() if line.strip().startswith(f"{label} {kind} "))
            assert f"{loop['gain_margin']:.3f} ({loop['gain_margin_db']:.1f})" in row, row
            assert f"{loop['phase_margin_deg']:.1f}" in row and f"{loop['bandwidth_rad_s']:.3f}" in row, row


def test_unusable_out_dir_exits_2_without_traceback(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    p = _vrsim("paper", "--out", str(blocker / "sub"))
    assert p.returncode == 2
    assert "Traceback" not in p.stderr and "--out" in p.stderr
