"""Bad vehicle input through the real `vrsim` executable: exit 2 and one clear stderr line each.

(The other bad inputs raise the same `VehicleError` and are covered by the unit tests.)"""

import os
import re
import subprocess

import pytest

from tests.conftest import ROOT, VRSIM

DATA = os.path.join(ROOT, "tests", "data", "vehicle")
RECT = 'rectangle = { width_m = 45.0, length_m = 300.0, lat = 52.0, lon = 10.0 }'

CASES = {
    "self_intersecting": (f'file = "{os.path.join(DATA, "bowtie.geojson")}"', "",
                          r"bowtie.geojson: boundary is invalid: Self-intersection"),
    "too_narrow": (f"{RECT}\nheadland_passes = 2\nturn_radius_m = 2.0", "",
                   r"too narrow for one swath inside 2 headland pass\(es\) of width_m=12.0"),
    "turn_radius": (f"{RECT}\nturn_radius_m = 40.0", "", r"cannot hold turn_radius_m=40.0"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_vehicle_input_exits_2_with_one_line(case, tmp_path):
    field, extra, message = CASES[case]
    scenario = tmp_path / f"{case}.toml"
    scenario.write_text(f'name = "{case}"\n[field]\n{field}\n[map]\nsynthetic = "uniform"\n{extra}')
    proc = subprocess.run([VRSIM, "run", str(scenario), "--quiet", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert re.search(message, lines[0]), lines[0]
