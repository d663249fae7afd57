"""The stage timer: a run's stages and wall time, read once (`services.sim.accounting.StageTimer`)."""

from types import SimpleNamespace

import pytest

from vrsim.services.sim import accounting
from vrsim.services.sim.accounting import StageTimer


@pytest.fixture
def clock(monkeypatch):
    """A perf_counter that reads ``clock.now`` (s)."""
    fake = SimpleNamespace(now=100.0)
    monkeypatch.setattr(accounting, "time", SimpleNamespace(perf_counter=lambda: fake.now))
    return fake


def test_a_run_in_this_process_counts_from_before_the_stages_it_was_given(clock):
    timer = StageTimer({"build_s": 1.0, "sumo_s": 2.0})   # as if they had just run: began at 97 s
    with timer.stage("control_s"):
        clock.now += 4.0
    with timer.stage("control_s"):   # a stage timed twice adds up
        clock.now += 0.5
    timer.add("metrics_s", 0.25)
    clock.now += 0.25
    timing = timer.timing()
    assert timing.stage_s == {"build_s": 1.0, "sumo_s": 2.0, "control_s": 4.5, "metrics_s": 0.25}
    assert timing.wall_time_s == 104.75 - 97.0
    timer.add("later_s", 1.0)
    assert "later_s" not in timing.stage_s   # a timing is a snapshot


def test_a_run_that_began_elsewhere_counts_from_its_start(clock):
    timer = StageTimer(started_s=90.0)
    with timer.stage("build_s"):
        clock.now += 1.0
    assert timer.timing().wall_time_s == 11.0


def test_shares_add_up_and_a_recorded_wall_time_is_kept(clock):
    shares = StageTimer({"control_s": 0.5, "metrics_s": 0.25}, shares=True)
    clock.now += 60.0   # others' work meanwhile is not this variant's
    assert shares.timing().wall_time_s == 0.75
    recorded = StageTimer({"build_s": 2.0}, wall_time_s=30.0)
    clock.now += 5.0
    assert recorded.timing().wall_time_s == 30.0
