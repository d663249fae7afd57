"""A run is complete only when it finished and every tick is stored: the monitor keeps the end scenario
control announces (first one), names the unstored tail, opens an older database without the end
columns, decodes the end as untrusted input; its report cache and rate limit."""

from __future__ import annotations

import sqlite3
import types

import pytest

from tests.unit.test_monitor_integrity import records, start
from vrsim.common import ServiceError
from vrsim.services.bus import messages, reads
from vrsim.services.bus.monitor import MonitorStore, _completeness
from vrsim.services.outputs.report import incomplete_note


def stored(tmp_path, ticks, end: messages.RunEnd | None = None) -> MonitorStore:
    store = MonitorStore(str(tmp_path / "m.sqlite"))
    store.add_run(start("r"))
    for table, recs in records("r", ticks).items():
        store.add(table, recs)
    if end is not None:
        store.set_end(end)
    return store


def facts(store: MonitorStore) -> dict:
    track, _ = store.arrays("r", sections=1, drives=1)
    return _completeness(track["tick"], store.end("r"))


def test_a_finished_run_with_every_tick_is_complete(tmp_path):
    store = stored(tmp_path, range(100), messages.RunEnd("r", "finished", 100, 5.0, ""))
    assert facts(store) == {"missing_ticks": [], "complete": True, "end_reason": "finished"}


def test_the_unstored_tail_up_to_the_announced_end_is_missing(tmp_path):
    store = stored(tmp_path, [*range(40), *range(60, 70)], messages.RunEnd("r", "finished", 177, 8.85, ""))
    assert facts(store) == {"missing_ticks": [[40, 59], [70, 176]], "complete": False,
                            "end_reason": "finished"}


@pytest.mark.parametrize("reason", ["stopped", "failed", "interrupted"])
def test_a_run_that_did_not_finish_is_not_complete_even_with_every_tick(tmp_path, reason):
    store = stored(tmp_path, range(50), messages.RunEnd("r", reason, 50, 2.5, ""))
    assert facts(store) == {"missing_ticks": [], "complete": False, "end_reason": reason}


def test_no_end_announced_is_unknown_and_not_complete(tmp_path):
    assert facts(stored(tmp_path, range(50))) == {"missing_ticks": [], "complete": False,
                                                   "end_reason": "unknown"}


def test_the_first_announced_end_stays(tmp_path):
    store = stored(tmp_path, range(10), messages.RunEnd("r", "stopped", 10, 0.5, ""))
    store.set_end(messages.RunEnd("r", "finished", 10, 0.5, ""))  # a second announcement: ignored
    assert store.end("r") == {"reason": "stopped", "ticks": 10, "sim_time_s": 0.5, "error": ""}


def test_an_older_database_without_the_end_columns_opens_and_gains_them(tmp_path):
    path = str(tmp_path / "old.sqlite")
    store = stored(tmp_path, range(10))
    store.close()
    db = sqlite3.connect(str(tmp_path / "m.sqlite"))
    db.execute("VACUUM INTO ?", (path,))
    db.close()
    old = sqlite3.connect(path)  # the runs table as schema 3 wrote it, before the end was stored
    for column in ("end_reason", "end_ticks", "end_sim_time_s", "end_error", "ended_unix"):
        old.execute(f"ALTER TABLE runs DROP COLUMN {column}")
    old.commit()
    old.close()
    reopened = MonitorStore(path)
    assert reopened.end("r") is None and reopened.counts("r")["complete"] == 10
    reopened.set_end(messages.RunEnd("r", "finished", 10, 0.5, ""))
    assert facts(reopened)["complete"] is True


def end_doc(**changes) -> dict:
    return {"run_id": "r", "reason": "finished", "ticks": 1, "sim_time_s": 0.0, "error": "", **changes}


@pytest.mark.parametrize("doc, message", [
    (end_doc(reason="done"), "reason must be one of"),
    (end_doc(ticks=-1), "ticks must be"),
    (end_doc(ticks=1.5), "field ticks must be int"),
    (end_doc(sim_time_s=None), "sim_time_s must be"),
    ({k: v for k, v in end_doc().items() if k != "error"}, "missing field 'error'"),
    (end_doc(error="x" * 3000), "error is over"),
])
def test_an_end_is_decoded_as_untrusted_input(doc, message):
    with pytest.raises(ServiceError, match=message):
        messages.RunEnd.from_dict(doc)


def test_the_note_says_how_many_ticks_and_why():
    summary = {"ticks": 67_850, "missing_ticks": [[67_850, 177_001]], "complete": False,
               "end_reason": "finished"}
    assert incomplete_note(summary) == "incomplete: 67,850 of 177,002 ticks stored; reason finished"
    whole = {"ticks": 5, "missing_ticks": [], "complete": True, "end_reason": "finished"}
    assert incomplete_note(whole) is None
    assert incomplete_note({"ticks": 5}) is None  # `vrsim run`'s summary has no such keys


def test_a_cached_report_answers_a_finished_run_until_its_records_change(monkeypatch):
    end = {"reason": "finished", "ticks": 10, "sim_time_s": 0.5, "error": ""}
    cached = reads.CachedReport((10, end), b"{}", made_s=0.0, took_s=1.0)
    assert cached.fresh((10, end)) and not cached.fresh((11, end))


def test_a_live_runs_report_is_remade_at_most_every_few_seconds_and_a_small_share_of_the_time(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(reads.time, "monotonic", lambda: now[0])
    quick = reads.CachedReport((10, None), b"{}", made_s=100.0, took_s=0.1)
    slow = reads.CachedReport((10, None), b"{}", made_s=100.0, took_s=1.0)
    now[0] = 104.0
    assert quick.fresh((500, None)) and slow.fresh((500, None))
    now[0] = 106.0
    assert not quick.fresh((500, None)) and slow.fresh((500, None))  # 1 s to make: not before 40 s
    now[0] = 141.0
    assert not slow.fresh((500, None))
    assert not quick.fresh((500, {"reason": "stopped"}))  # the end came: made again at once


def test_the_rate_limit_refuses_beyond_its_burst_and_refills(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(reads.time, "monotonic", lambda: now[0])
    limit = reads.RateLimit(5.0, 3)
    for _ in range(3):
        limit.take("k/report")
    with pytest.raises(ServiceError, match=r"k/report: too many report queries \(at most 5 a second"):
        limit.take("k/report")
    now[0] = 0.2  # one token back
    limit.take("k/report")
    with pytest.raises(ServiceError):
        limit.take("k/report")


def test_a_refusal_is_answered_late_so_a_loop_asks_slowly(monkeypatch):
    slept = []
    clock = types.SimpleNamespace(monotonic=reads.time.monotonic, sleep=slept.append)
    monkeypatch.setattr(reads, "time", clock)
    limit = reads.RateLimit(0.001, 1)
    assert limit.admit("k/report") is None
    late = limit.admit("k/report")
    assert slept == []  # admitting it did not wait: the refusal's own work does
    with pytest.raises(ServiceError, match="too many report queries"):
        late.work()
    assert slept == [reads.REFUSAL_DELAY_S]


def test_the_monitor_makes_a_report_once_per_change_and_refuses_a_flood(tmp_path, monkeypatch):
    from vrsim.services.bus.dataroot import DataRoot
    from vrsim.services.bus.monitor import _MonitorService
    from vrsim.services.bus.serving import Later, Params

    monkeypatch.setattr("vrsim.services.sim.as_run.with_settings", lambda result: result)
    monkeypatch.setattr("vrsim.services.outputs.summary.summary_json", lambda result: str(result))
    store = stored(tmp_path, range(10), messages.RunEnd("r", "finished", 20, 1.0, ""))
    svc = _MonitorService(store, DataRoot(str(tmp_path)))
    made = []
    monkeypatch.setattr(svc, "_report", lambda run_id: made.append(run_id) or len(made))

    def ask():
        return svc.report(Params("k/report", [("run_id", "r")]), None)

    assert ask() == ask() == b"1" and made == ["r"]
    for table, recs in records("r", range(10, 20)).items():  # late records: made again, once
        store.add(table, recs)
    assert ask() == ask() == b"2"
    replies = [ask() for _ in range(10)]
    assert isinstance(replies[-1], Later) and len(made) == 2
