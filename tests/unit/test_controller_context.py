"""The controller's context: a step with a third argument gets ground speed, rate, sections, time and
the plant's gain every period; a two-argument step is called as before (decided once, at build); the
gain-schedule example of docs/controllers.md is the file it names, and it runs."""

import dataclasses
import os
import re

import numpy as np
import pytest

from vrsim.common import ControllerError
from vrsim.controller import (
    ClosedLoop,
    ControllerConfig,
    PidGains,
    PlantLoop,
    PlantParams,
    build_loop,
    loop_info,
)
from vrsim.controller import plant_loop as plant_loop_module
from vrsim.controller.context import ContextTrack, ControlContext, takes_context

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLE = os.path.join(ROOT, "scenarios", "speed_scheduled_pi.py")
MY_CONTROLLER = os.path.join(ROOT, "scenarios", "my_controller.py")
T = 0.05


class Recorder:
    """A context-taking P controller that keeps every context it was given."""

    def __init__(self, params, loop, n):
        self.n, self.seen = n, []

    def step(self, target_rpm, measured_rpm, context):
        self.seen.append(context)
        return 0.004 * (target_rpm - measured_rpm) + target_rpm / context.shaft_rpm_per_a

    def reset(self):
        pass

    def state(self):
        return {}

    def set_state(self, state):
        pass


class TwoArguments(Recorder):
    """The same law without the context (its plant gain written in)."""

    def step(self, target_rpm, measured_rpm):
        return 0.004 * (target_rpm - measured_rpm) + target_rpm / PlantParams().shaft_rpm_per_a


def _track(k: int, sections: int = 3) -> ContextTrack:
    rng = np.random.default_rng(5)
    return ContextTrack(rng.uniform(0.5, 4.0, k), rng.uniform(80.0, 200.0, k),
                        rng.random((k, sections)) > 0.3)


@pytest.mark.parametrize("n", [1, 3])
def test_a_three_argument_step_gets_the_context_of_each_period(n):
    plant, k = PlantParams(), 40
    track = _track(k)
    targets = np.linspace(20.0, 140.0, k)
    loop = PlantLoop(loop_info(plant), Recorder({}, None, n), n=n)
    out = loop.run(np.broadcast_to(targets[:, None], (k, n)) if n > 1 else targets, context=track)
    seen = loop.controller.seen
    assert len(seen) == k and all(isinstance(c, ControlContext) for c in seen)
    for i, c in enumerate(seen):
        assert c.target_rpm.shape == c.measured_rpm.shape == c.speed_m_s.shape == (n,)
        assert c.sections_on.shape == (n, 3) and c.sections_on.dtype == bool
        assert np.all(c.speed_m_s == track.speed_m_s[i])
        assert np.all(c.prescribed_kg_ha == track.prescribed_kg_ha[i])
        assert np.all(c.sections_on == track.sections_on[i]) and c.time_s == pytest.approx(i * T)
        assert c.shaft_rpm_per_a == plant.shaft_rpm_per_a == pytest.approx(250.0, rel=1e-5)
        assert np.all(c.target_rpm == targets[i]) and np.all(c.measured_rpm == out.measured_rpm[i])
    with pytest.raises(ValueError):
        seen[-1].speed_m_s[0] = 1.0       # read-only: a controller cannot change the run's arrays
    with pytest.raises(dataclasses.FrozenInstanceError):
        seen[-1].time_s = 0.0


def test_each_loop_gets_its_own_speed_and_rate_from_a_track_of_each_loops_values():
    """A track of (K, n) speeds and rates (a metering drive per loop) gives loop j column j; a track
    of another number of loops' values is refused naming the field."""
    plant, k, n = PlantParams(), 30, 3
    rng = np.random.default_rng(7)
    speed, rate = rng.uniform(0.5, 4.0, (k, n)), rng.uniform(80.0, 200.0, (k, n))
    track = ContextTrack(speed, rate, rng.random((k, 2)) > 0.3)
    loop = PlantLoop(loop_info(plant), Recorder({}, None, n), n=n)
    loop.run(np.full((k, n), 80.0), context=track)
    seen = loop.controller.seen
    np.testing.assert_array_equal([c.speed_m_s for c in seen], speed)
    np.testing.assert_array_equal([c.prescribed_kg_ha for c in seen], rate)
    with pytest.raises(ControllerError, match="speed_m_s has 3 loops' values, the loop runs 2"):
        PlantLoop(loop_info(plant), Recorder({}, None, 2), n=2).run(np.full((k, 2), 80.0), context=track)
    with pytest.raises(ControllerError, match=r"speed \(K,\) or \(K, n\)"):
        ContextTrack(speed, rate[:-1], track.sections_on)


def test_a_two_argument_step_runs_as_before_and_the_signature_is_read_once(monkeypatch):
    calls = []
    real = plant_loop_module.takes_context
    monkeypatch.setattr(plant_loop_module, "takes_context", lambda step: calls.append(step) or real(step))
    targets = np.linspace(20.0, 140.0, 200)
    old = PlantLoop(loop_info(PlantParams()), TwoArguments({}, None, 1)).run(targets, context=_track(200))
    new = PlantLoop(loop_info(PlantParams()), Recorder({}, None, 1)).run(targets, context=_track(200))
    assert len(calls) == 2            # once per loop built, not per period
    np.testing.assert_array_equal(old.current_a, new.current_a)
    assert not takes_context(TwoArguments({}, None, 1).step) and takes_context(Recorder({}, None, 1).step)


def test_without_a_drive_speed_and_rate_are_nan_and_time_survives_a_state_round_trip():
    loop = PlantLoop(loop_info(PlantParams()), Recorder({}, None, 1))
    loop.run(np.full(30, 100.0))
    c = loop.controller.seen[-1]
    assert np.isnan(c.speed_m_s).all() and np.isnan(c.prescribed_kg_ha).all()
    assert c.sections_on.shape == (1, 0)
    state = loop.state
    again = PlantLoop(loop_info(PlantParams()), Recorder({}, None, 1))
    again.set_state(state)
    for each in (loop, again):
        each.run(np.full(5, 100.0), context=_track(5))
    assert again.controller.seen[-1].time_s == loop.controller.seen[-1].time_s == pytest.approx(34 * T)
    loop.reset()
    loop.step(100.0)
    assert loop.controller.seen[-1].time_s == 0.0
    with pytest.raises(ControllerError, match="context must cover"):
        loop.run(np.full(4, 100.0), context=_track(5))


def test_loops_that_read_no_context_give_the_same_numbers_with_one():
    targets, track = np.linspace(20.0, 140.0, 100), _track(100)
    for cfg in (ControllerConfig(), ControllerConfig(kind="ideal"), ControllerConfig(kind="aog_pi"),
                ControllerConfig(kind="python", file=MY_CONTROLLER, class_name="MyController")):
        a = build_loop(PlantParams(), cfg).run(targets)
        b = build_loop(PlantParams(), cfg).run(targets, context=track)
        np.testing.assert_array_equal(a.shaft_rev, b.shaft_rev)
    loop = ClosedLoop(PlantParams(), [PidGains(1.0, 5.0, 0.0)] * 2, n=2)
    assert loop.run(np.column_stack([targets, targets]), context=track).shaft_rev.shape == (100, 2)


def _doc_example() -> str:
    """The Python block under docs/controllers.md's "A gain schedule on ground speed"."""
    with open(os.path.join(ROOT, "docs", "controllers.md"), encoding="utf-8") as fh:
        doc = fh.read()
    section = doc[doc.index("### A gain schedule on ground speed"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_docs_gain_schedule_is_the_example_file():
    with open(EXAMPLE, encoding="utf-8") as fh:
        text = fh.read()
    assert text.endswith(_doc_example()) and text.index("import numpy") == text.index(_doc_example())


def _schedule_loop(path, params, n=1):
    cfg = ControllerConfig(kind="python", file=str(path), class_name="SpeedScheduledPI", params=params)
    return build_loop(PlantParams(), cfg, n=n)


def test_the_docs_gain_schedule_runs_its_gains_on_ground_speed(tmp_path):
    path = tmp_path / "from_the_doc.py"
    path.write_text(_doc_example())
    schedule = {"speed_m_s": [1.0, 4.0], "kp_a_per_rpm": [0.003, 0.0015], "ki_a_per_rpm_s": [0.012, 0.006]}
    targets, k = np.repeat([60.0, 120.0, 90.0], 60), 180

    def run(params, speed_m_s):
        track = ContextTrack(np.full(k, speed_m_s), np.full(k, 150.0), np.ones((k, 2), bool))
        return _schedule_loop(path, params).run(targets, context=track).current_a[:, 0]

    def flat(i):
        return {"speed_m_s": [1.0, 4.0], **{g: [v[i], v[i]] for g, v in schedule.items() if g != "speed_m_s"}}

    slow, fast = run(schedule, 0.5), run(schedule, 6.0)
    np.testing.assert_array_equal(slow, run(flat(0), 2.5))     # below the first breakpoint: its gains
    np.testing.assert_array_equal(fast, run(flat(1), 2.5))     # above the last: its gains
    assert not np.array_equal(slow, fast) and not np.array_equal(run(schedule, 2.5), slow)
    # without a drive (a step response: NaN speed) it runs at the first breakpoint's gains, for any n
    no_drive = _schedule_loop(path, schedule, n=2).run(np.column_stack([targets, targets])).current_a
    np.testing.assert_allclose(no_drive[:, 0], slow, rtol=1e-12)
    with pytest.raises(ControllerError, match="rejected its params"):
        _schedule_loop(path, {"speed_m_s": [4.0, 1.0]})
