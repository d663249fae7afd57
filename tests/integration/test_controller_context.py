"""A field run hands a context-taking controller the drive's context (real SUMO on a small field): the
sensed ground speed, the prescription and the sections of each tick, and the time; the variants'
batch (sweeps, `vrsim tune`) hands it the same, so both give the same figures."""

import hashlib
import os
import sys

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.integration.test_variants import FIELD, assert_same_summary
from vrsim.controller import ControllerConfig
from vrsim.services.sim import scenario
from vrsim.services.sim.run import control_and_account, drive
from vrsim.services.sim.variants import run_variants

# Two context-taking P controllers in one user file, over a base without memory.
RECORDERS = '''
import numpy as np


class _NoMemory:
    def __init__(self, params, loop, n):
        self.n = n

    def reset(self):
        pass

    def state(self):
        return {}

    def set_state(self, state):
        pass


class Recorder(_NoMemory):
    """A P controller on the schedule of speed that keeps the context of every period."""

    seen = []

    def step(self, target_rpm, measured_rpm, context):
        c = context
        Recorder.seen.append((c.speed_m_s[0], c.prescribed_kg_ha[0], c.sections_on[0].copy(), c.time_s))
        kp = np.interp(context.speed_m_s, [1.0, 3.0], [0.004, 0.001])
        return target_rpm / context.shaft_rpm_per_a + kp * (target_rpm - measured_rpm)


class DrivesRecorder(_NoMemory):
    """A P controller that keeps each loop's speed and prescription of every period."""

    seen = []

    def step(self, target_rpm, measured_rpm, context):
        DrivesRecorder.seen.append((context.speed_m_s.copy(), context.prescribed_kg_ha.copy()))
        return target_rpm / context.shaft_rpm_per_a + 0.002 * (target_rpm - measured_rpm)
'''


@pytest.fixture(scope="module")
def shared_drive():
    return drive(scenario.parse(FIELD, "context.toml", "."))


def _recorded(path: str, class_name: str = "Recorder") -> list:
    """What class `class_name` loaded last from `path` recorded (`controller.kinds.python` names its
    module)."""
    return getattr(sys.modules[f"vrsim_user_{hashlib.sha1(path.encode()).hexdigest()[:12]}"], class_name).seen


def test_a_field_run_gives_the_controller_each_ticks_speed_rate_sections_and_time(shared_drive, tmp_path):
    path = str(tmp_path / "recorder.py")
    with open(path, "w") as fh:
        fh.write(RECORDERS)
    cfg = ControllerConfig(kind="python", file=path, class_name="Recorder")
    result = control_and_account(shared_drive, cfg)
    seen = _recorded(path)
    ticks = len(result.control["target_shaft_rpm"])
    assert len(seen) == ticks
    speed, rate, sections, time_s = (np.array(column) for column in zip(*seen, strict=True))
    np.testing.assert_array_equal(speed, shared_drive.measured_speed_m_s)
    np.testing.assert_array_equal(rate, result.control["prescribed_kg_ha"])
    np.testing.assert_array_equal(sections, result.control["sections_on"])
    assert sections.shape[1] == 4 and sections.any() and not sections.all()
    np.testing.assert_allclose(time_s, np.arange(ticks) * 0.05, atol=1e-9)
    # the variants' batch passes the same context: the same figures as the field run
    fast = run_variants(shared_drive, [cfg, ControllerConfig(kind="PID")])[0]
    assert_same_summary(fast, result.summary)


def test_the_docs_gain_schedule_runs_a_field(shared_drive):
    example = os.path.join(ROOT, "scenarios", "speed_scheduled_pi.py")
    cfg = ControllerConfig(kind="python", file=example, class_name="SpeedScheduledPI")
    flat = ControllerConfig(kind="python", file=example, class_name="SpeedScheduledPI",
                            params={"kp_a_per_rpm": [0.0015, 0.0015], "ki_a_per_rpm_s": [0.006, 0.006]})
    scheduled, fixed = run_variants(shared_drive, [cfg, flat])
    assert scheduled["mae_kg_ha"] < 20.0 and scheduled["mae_kg_ha"] != fixed["mae_kg_ha"]


def test_each_drive_of_a_drive_per_section_gets_its_own_speed_and_prescription(tmp_path):
    """``section_drives``: each loop's context carries its own drive's rate (its section's landing
    point) and ground speed (its section's own in a turn: turn compensation), not the machine's; the
    variants' batch maps each column to its drive, giving the field run's figures."""
    path = str(tmp_path / "drives_recorder.py")
    with open(path, "w") as fh:
        fh.write(RECORDERS)
    field = drive(scenario.with_changes(scenario.parse(FIELD, "drives.toml", "."),
                                        implement={"kind": "section_drives"}))
    cfg = ControllerConfig(kind="python", file=path, class_name="DrivesRecorder")
    result = control_and_account(field, cfg)
    seen = _recorded(path, "DrivesRecorder")
    speed, rate = (np.array(column) for column in zip(*seen, strict=True))
    assert speed.shape == rate.shape == result.control["drive_rate_kg_ha"].shape == (len(seen), 4)
    np.testing.assert_array_equal(rate, result.control["drive_rate_kg_ha"])
    assert (rate.max(axis=1) > rate.min(axis=1)).sum() > 100    # zone edges under the boom
    turning = speed.max(axis=1) - speed.min(axis=1) > 0.1      # inner and outer sections in the turns
    assert turning.sum() > 50
    moving = (speed > 0).all(axis=1)   # symmetric sections: their speeds average the centre's
    np.testing.assert_allclose(speed[moving].mean(axis=1), field.measured_speed_m_s[moving], atol=1e-9)
    fast = run_variants(field, [cfg, ControllerConfig(kind="PID")])[0]
    assert_same_summary(fast, result.summary)
