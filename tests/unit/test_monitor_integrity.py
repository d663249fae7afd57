"""The monitor's store keeps the first record of a tick, knows its runs across restarts, and gives every
complete tick with the gaps named. (Forged records over a real bus: tests/integration.)"""

from __future__ import annotations

import numpy as np
import pytest

from vrsim.common import ServiceError
from vrsim.services.bus import messages, monitor
from vrsim.services.bus.monitor import MonitorStore, _missing_ticks


def start(run_id: str) -> messages.RunStart:
    return messages.RunStart(run_id, "", "s.toml", "/", "lockstep", 1.0, 50)


def records(run_id: str, ticks, x_m: float = 1.0):
    pose = [messages.Pose(run_id, t, 0.05 * t, x_m, 2.0, x_m, 2.0, 0.0, 2.0, 2.0, True, 0.1 * t)
            for t in ticks]
    shaft = [messages.ShaftState(run_id, t, 0.05 * t, 50.0, 49.0, 0.04, 0.2, [50.0]) for t in ticks]
    rate = [messages.RateSample(run_id, t, 0.05 * t, 1.0, 2.0, 200.0, 199.0, 0.04, 12.0, "0x1", True,
                                 [200.0], [0.04])
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
    track, _ = store.arrays("r", sections=1, drives=1)
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
    track, control = store.arrays("r", sections=1, drives=1)
    assert track["tick"].tolist() == stored
    assert len(control["metered_kg"]) == len(stored)
    assert _missing_ticks(track["tick"]) == [[100, 249]]


def test_each_drives_values_are_stored_and_rebuilt_and_a_record_that_does_not_fit_the_machine_is_named(
        tmp_path):
    """A run of three metering drives: each drive's target and product come back from the database as
    (ticks, drives) arrays bit for bit (and as the records published); a record with another number of
    drives than the run's machine has is a `ServiceError` naming the run, stream, tick and count."""
    store = MonitorStore(str(tmp_path / "m.sqlite"))
    store.add_run(start("r"))
    recs = records("r", range(4))
    kg = np.random.default_rng(1).random((4, 3)) / 7
    for t in range(4):
        recs["shaft"][t].drive_target_rpm = [50.0 + t, 0.0, 1 / 3]
        recs["rate"][t].drive_kg = kg[t].tolist()
        recs["rate"][t].drive_rate_kg_ha = [200.0, float("nan"), 180.0 + t]
    recs["rate"][2].drive_kg[1] = float("nan")
    for table, batch in recs.items():
        store.add(table, batch)
    _, control = store.arrays("r", sections=1, drives=3)
    want = kg.copy()
    want[2, 1] = np.nan
    np.testing.assert_array_equal(control["drive_kg"], want)
    np.testing.assert_array_equal(control["drive_target_rpm"][:, 0], [50.0, 51.0, 52.0, 53.0])
    assert control["drive_target_rpm"][0, 2] == 1 / 3
    assert np.isnan(control["drive_rate_kg_ha"][:, 1]).all() and control["drive_rate_kg_ha"][3, 2] == 183.0
    back = store.records("rate", "r", 0, 4)
    assert back[0].drive_kg == kg[0].tolist() and np.isnan(back[2].drive_kg[1])
    short = records("r", [4])
    short["rate"][0].drive_kg = [0.1, 0.2]
    short["rate"][0].drive_rate_kg_ha = [1.0, 2.0, 3.0]
    short["shaft"][0].drive_target_rpm = [1.0, 2.0, 3.0]
    for table, batch in short.items():
        store.add(table, batch)
    with pytest.raises(ServiceError, match=r"^r: rate records: tick 4: drive_kg holds 2 values, the "
                                           r"machine has 3 drives$"):
        store.arrays("r", sections=1, drives=3)


def test_a_records_reply_of_many_drives_holds_fewer_records_within_the_values_cap(tmp_path, monkeypatch):
    """`monitor/records` gives fewer records than asked for where each holds many drives' values, so
    that a reply stays within `MAX_VALUES` (the web service reads on from the last tick it got)."""
    monkeypatch.setattr(monitor, "MAX_VALUES", 100)
    store = MonitorStore(str(tmp_path / "m.sqlite"))
    store.add_run(start("r"))
    recs = records("r", range(10))
    for r in recs["rate"]:
        r.drive_kg = r.drive_rate_kg_ha = [0.01] * 5   # 8 other fields + 2 x 5 values: 18 a record
    for table, batch in recs.items():
        store.add(table, batch)
    assert [r.tick for r in store.records("rate", "r", 2, 10)] == [2, 3, 4, 5, 6]   # 5 x 18 <= 100
    assert len(store.records("pose", "r", 0, 10)) == 10   # 10 x 10 values
