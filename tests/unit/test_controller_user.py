"""User-defined controllers (kind "python"): the example in scenarios/ runs through the same loop as the
built-in kinds, and errors in user code name the user's file, line, key and value."""

import json
import os
import textwrap
from dataclasses import replace

import numpy as np
import pytest

from vrsim.common import ControllerError, VrsimError
from vrsim.controller import ControllerConfig, PlantParams, UserCodeError, build_loop

P = PlantParams()
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLE = os.path.join(ROOT, "scenarios", "my_controller.py")


def user(path, cls="MyController", **params):
    return ControllerConfig(kind="python", file=str(path), class_name=cls, params=params)


def test_example_controller_equals_the_built_in_positional_pi_with_the_same_gains():
    kp_a, ki_a = 0.003, 0.02       # A/rpm, A/(rpm s)
    volts = P.amplifier_gain_a_per_v * P.sensor_gain_v_per_rpm       # A per rpm of error at 1 V/V
    built_in = ControllerConfig(kind="PI", form="positional", gains="manual", kp=kp_a / volts,
                                ki=ki_a / volts)
    weak = replace(P, current_max_a=0.82)                      # 200 rpm needs 0.8 A: saturates on the way
    targets = np.r_[np.full(60, 120.0), np.full(60, 30.0), np.full(60, 200.0), np.full(60, 0.0)]
    mine = build_loop(weak, user(EXAMPLE, kp_a_per_rpm=kp_a, ki_a_per_rpm_s=ki_a)).run(targets)
    theirs = build_loop(weak, built_in).run(targets)
    assert mine.current_a.max() == 0.82 and mine.current_a.min() == 0.0   # anti-windup is exercised
    for name in ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm"):
        x = getattr(theirs, name)
        np.testing.assert_allclose(getattr(mine, name), x, rtol=1e-9, atol=1e-9 * np.abs(x).max())


def test_user_controller_state_round_trips_through_json():
    cfg = user(EXAMPLE)
    a = build_loop(P, cfg, n=2)
    a.run(np.full((30, 2), 90.0))
    saved = json.loads(json.dumps(a.state, default=lambda x: x.tolist()))
    rest = a.run(np.full((30, 2), 45.0))
    b = build_loop(P, cfg, n=2)
    b.set_state(saved)
    np.testing.assert_array_equal(b.run(np.full((30, 2), 45.0)).shaft_rpm, rest.shaft_rpm)


def write(tmp_path, body, name="ctl.py"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(body))
    return path


GOOD = """\
import numpy as np

class Ctl:
    def __init__(self, params, loop, n):
        self.n = n
        self.gain = params["gain"]
    def step(self, target_rpm, measured_rpm):
        return {step_body}
    def reset(self):
        pass
    def state(self):
        return {{}}
    def set_state(self, state):
        pass
"""


def test_a_crash_inside_user_code_names_file_and_line(tmp_path):
    path = write(tmp_path, GOOD.format(step_body="np.full(self.n, 0.1) / (self.gain - self.gain)[0]"))
    loop = build_loop(P, user(path, "Ctl", gain=1.0))
    with pytest.raises(UserCodeError) as err:
        loop.step(100.0)
    assert not isinstance(err.value, VrsimError)          # a crash: the CLI's exit 1, not 2
    assert err.value.file == str(path) and err.value.line == 8
    assert f"{path}:8: Ctl.step raised TypeError" in str(err.value)
    assert "Traceback" in err.value.user_traceback


def test_bad_params_name_the_file_key_and_value(tmp_path):
    path = write(tmp_path, GOOD.format(step_body="np.full(self.n, self.gain)"))
    message = rf"{path}:6: Ctl rejected its params {{'gian': 1.0}}: KeyError: 'gain'"
    with pytest.raises(ControllerError, match=message):
        build_loop(P, user(path, "Ctl", gian=1.0))
    with pytest.raises(ControllerError, match=r"my_controller.py:\d+: MyController rejected its params .*"
                                              r"ValueError: gains must be >= 0.*kp_a_per_rpm=-1.0"):
        build_loop(P, user(EXAMPLE, kp_a_per_rpm=-1.0))


def test_bad_output_names_the_controller(tmp_path):
    path = write(tmp_path, GOOD.format(step_body="np.full(self.n + 1, self.gain)"))
    with pytest.raises(ControllerError, match=r"ctl.py:Ctl.step must return 1 currents"):
        build_loop(P, user(path, "Ctl", gain=0.1)).step(100.0)
    path = write(tmp_path, GOOD.format(step_body="np.full(self.n, np.nan)"), "nan.py")
    with pytest.raises(ControllerError, match=r"nan.py:Ctl.step must return finite currents"):
        build_loop(P, user(path, "Ctl", gain=0.1)).step(100.0)


@pytest.mark.parametrize("body,cls,message", [
    ("class Ctl:\n    pass\n", "Other", r"ctl.py: no class 'Other' \(classes in it: Ctl\)"),
    ("class Ctl:\n    def step(self, r, m):\n        return r\n", "Ctl",
     r"class Ctl has no method reset\(\)"),
    ("Ctl = 3\n", "Ctl", r"class Ctl is not a class"),
    ("class Ctl:\n    def step(self\n", "Ctl", r"ctl.py:2: cannot be loaded: SyntaxError"),
    ("import numpy\nraise RuntimeError('no licence')\n", "Ctl",
     r"ctl.py:2: cannot be loaded: RuntimeError: no lic"),
    (GOOD.format(step_body="0").replace("def __init__(self, params, loop, n)", "def __init__(self)"), "Ctl",
     r"Ctl.__init__ must take \(params, loop, n\)"),
])
def test_bad_class_is_a_controller_error_naming_the_file(tmp_path, body, cls, message):
    path = write(tmp_path, body)
    with pytest.raises(ControllerError, match=message):
        build_loop(P, user(path, cls, gain=1.0))


def test_missing_file_and_relative_path_are_reported(tmp_path):
    with pytest.raises(ControllerError, match=r"nowhere.py: no such file"):
        build_loop(P, user(tmp_path / "nowhere.py", "X"))
    with pytest.raises(ControllerError, match=r"must be an absolute path"):
        build_loop(P, user("relative.py", "X"))


def test_example_controllers_linear_model_gives_the_built_in_pis_margins():
    from vrsim.controller.analysis import analyze_loop

    kp_a, ki_a = 0.0015, 0.008
    volts = P.amplifier_gain_a_per_v * P.sensor_gain_v_per_rpm
    built_in = ControllerConfig(kind="PI", form="positional", gains="manual", kp=kp_a / volts,
                                ki=ki_a / volts)
    mine = analyze_loop(P, user(EXAMPLE, kp_a_per_rpm=kp_a, ki_a_per_rpm_s=ki_a))
    theirs = analyze_loop(P, built_in)
    for name in ("gain_margin", "phase_margin_deg", "crossover_rad_s", "bandwidth_rad_s"):
        assert getattr(mine, name) == pytest.approx(getattr(theirs, name), rel=1e-9), name
