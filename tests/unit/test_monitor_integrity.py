"""The monitor's store keeps the first record of a tick, knows its runs across restarts, and gives every
complete tick with the gaps named. (Forged records over a real bus: tests/integration.)"""

from __future__ import annotations

import numpy as np
import pytest

from services.bus import messages
from services.bus.monitor import MonitorStore, _missing_ticks


def start(run_id: str) -> messages.RunStart:
    return messages.RunStart(run_id, "", "s.toml", "/", "lockstep", 1.0, 50)


def records(run_id: str, ticks, x_m: float = 1.0):
    pose = [messages.Pose(run_id, t, 0.05 * t, x_m, 2.0, x_m, 2.0, 0.0, 2.0, 2.0, True, 0.1 * t)
            for t in ticks]
    shaft = [messages.ShaftState(run_id, t, 0.05 * t, 50.0, 49.0, 0.04, 0.2) for t in ticks]
    rate = [messages.RateSample(run_id, t, 0.05 * t, 1.0, 2.0, 200.0, 199.0, 0.04, 12.0, "0x1", True)
            for t in ticks]
    return {"pose": pose, "shaft": shaft, "rate": rate}


@pytest.mark.parametrize("ticks, gaps", [
    ([0, 1, 2], []),
    ([0, 1, 5, 6, 9], [[2, 4], [7, 8]]),
    ([3, 4], [[0, 2]]),
    ([], []),
])
def test_missing_ticks_are_ranges_up_to_the_last_stored(ticks, gaps):
    assert _missing_ticks(np.array(ticks)) == gaps


def test_a_second_record_of_a_tick_never_replaces_the_first(tmp_path):
    store = MonitorStore(str(tmp_path / "m.sqlite"))
    store.add_run(start("r"))
    for table, recs in records("r", range(10)).items():
        store.add(table, recs)
    last = store.run("r")["last_unix"]
    for table, recs in records("r", range(10), x_m=999.0).items():  # forged: same ticks, other values
        store.add(table, recs)
    assert store.run("r")["last_unix"] == last
    track, _ = store.arrays("r", sections=1)
    assert track["x_m"].tolist() == [1.0] * 10
    assert store.counts("r") == {"pose": 10, "shaft": 10, "rate": 10, "complete": 10}


def test_a_second_announcement_keeps_the_run_and_runs_survive_a_restart(tmp_path):
    path = str(tmp_path / "m.sqlite")
    store = MonitorStore(path)
    store.add_run(start("a"))
    first = store.run("a")
    store.add_run(start("a"))
    assert store.run("a") == first
    store.db.close()
    assert MonitorStore(path).run_ids() == {"a"}


def test_arrays_hold_every_complete_tick_across_gaps(tmp_path):
    store = MonitorStore(str(tmp_path / "m.sqlite"))
    store.add_run(start("r"))
    stored = [*range(0, 100), *range(250, 400)]
    for table, recs in records("r", stored).items():
        store.add(table, recs)
    store.add("pose", records("r", [400, 401])["pose"])  # in flight: pose only
    track, control = store.arrays("r", sections=1)
    assert track["tick"].tolist() == stored
    assert len(control["metered_kg"]) == len(stored)
    assert _missing_ticks(track["tick"]) == [[100, 249]]
