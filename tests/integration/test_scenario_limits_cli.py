"""`vrsim run` on scenarios that used to fail unclearly (issue #16): a seed SUMO cannot take, a control
period or time limit out of range or out of reach, gains that overflow, TOML nested thousands deep, a
scenario file that is a FIFO or a device. Each is refused at once with one line naming the file, the
table and the key, exit 2, no warning and no traceback."""

from __future__ import annotations

import os
import subprocess
import time

import pytest

from tests.conftest import VRSIM

FIELD = '[field]\nrectangle = { width_m = 36.0, length_m = 60.0, lat = 52.1, lon = 11.6 }\n'
MAP = '[map]\nsynthetic = "uniform"\n'
CASES = {
    "seed = 2^31": (f"seed = 2147483648\n{FIELD}{MAP}", "seed must be in [0, 2147483647], got 2147483648"),
    "control_period_s = 100 s": (f"{FIELD}{MAP}[timing]\ncontrol_period_s = 100.0\nplant_step_s = 0.001\n",
                                 "[timing] control_period_s must be in [0.001, 1] s"),
    "max_sim_time_s out of reach": (f"{FIELD}{MAP}[timing]\nmax_sim_time_s = 20.0\n",
                                    "[timing] max_sim_time_s = 20 s cannot be met"),
    "kp = ki = 1e308": (f'{FIELD}{MAP}[controller]\ngains = "manual"\nkp = 1e308\nki = 1e308\n',
                        "[controller] controller pid kp must be a number in [0, 1e+06], got 1e+308"),
    "arrays nested 5,000 deep": ("x = " + "[" * 5000 + "]" * 5000 + "\n", "values nested too deeply"),
}


def run(path: str, tmp_path) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.monotonic()
    done = subprocess.run([VRSIM, "run", path, "--quiet", "--out", str(tmp_path / "out")],
                          capture_output=True, timeout=120)
    return done, time.monotonic() - t0


@pytest.mark.parametrize("case", CASES)
def test_a_bad_value_is_one_line_naming_file_table_and_key(case, tmp_path):
    text, needle = CASES[case]
    path = tmp_path / "bad.toml"
    path.write_text(text)
    done, took = run(str(path), tmp_path)
    err = done.stderr.decode()
    assert done.returncode == 2 and err.startswith(f"vrsim run: error: {path}: ") and needle in err, err
    assert len(err.splitlines()) == 1 and "Warning" not in err and "Traceback" not in err, err
    message = err.strip()[len(f"vrsim run: error: {path}: "):]
    print(f"\n#16 case | vrsim run: {case} | exit 2 in {took:.1f} s: {message}")


@pytest.mark.parametrize("make, needle", [(os.mkfifo, "is a FIFO"),
                                          (lambda p: os.symlink("/dev/zero", p), "is a device")])
def test_a_scenario_file_that_is_a_fifo_or_a_device_is_refused_at_once(make, needle, tmp_path):
    path = str(tmp_path / "s.toml")
    make(path)
    done, took = run(path, tmp_path)
    err = done.stderr.decode()
    assert done.returncode == 2 and f"{path}: {needle}" in err and len(err.splitlines()) == 1, err
    print(f"\n#16 case | vrsim run: the scenario file {needle[3:]} | exit 2 in {took:.1f} s")
