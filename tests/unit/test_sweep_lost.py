"""Lost and failed runs of a sweep without a cluster: how an outcome is told apart, how a spell without
a worker is watched, what `--resume` keeps, and a plan's size before it is planned."""

import pytest

from vrsim.services.batch import driver
from vrsim.services.outputs.sweep_results import ResultsTable, _write_parquet
from vrsim.services.sim.sweep import parse_sweep, planned_runs


class _Future:
    def __init__(self, status, result=None, exc=None):
        self.status, self._result, self._exc = status, result, exc

    def result(self, timeout=None):
        if self._exc is not None:
            raise self._exc
        return self._result


def test_a_task_that_raised_failed_and_one_the_cluster_dropped_is_lost():
    from distributed.comm.core import CommClosedError

    assert driver._outcome(_Future("finished", 4)) == (4, None, False)
    assert driver._outcome(_Future("error", exc=ValueError("bad kp"))) == (None, "ValueError: bad kp", False)
    result, error, lost = driver._outcome(_Future("cancelled"))
    assert (result, lost) == (None, True) and error.startswith("lost: the cluster cancelled this task")
    # Its own OSError is the task's failure; the same class while fetching a result is the cluster's.
    assert driver._outcome(_Future("error", exc=OSError("disk"))) == (None, "OSError: disk", False)
    assert driver._outcome(_Future("pending", exc=CommClosedError("gone"))) == \
        (None, "lost: CommClosedError: gone", True)
    # A result being recomputed (its worker died) is asked again later, not waited for here.
    assert driver._outcome(_Future("lost", exc=TimeoutError())) is None
    assert driver._outcome(_Future("error", exc=TimeoutError("slow"))) == (None, "TimeoutError: slow", False)


class _Client:
    def __init__(self):
        self.status, self.n_workers = "running", 1

    def scheduler_info(self):
        return {"n_workers": self.n_workers, "workers": {}}


@pytest.fixture
def clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(driver.time, "monotonic", lambda: now[0])
    return now


def test_a_spell_without_a_worker_is_said_once_after_the_notice_and_waits_without_a_timeout(clock):
    client, said = _Client(), []
    watch = driver._NoWorkerWatch(client, 10.0, None, said.append)
    assert not watch.expired()
    client.n_workers = 0
    for t in (100.0, 105.0, 109.9):
        clock[0] = t
        assert not watch.expired()
    assert said == []
    clock[0] = 110.0
    assert not watch.expired() and said == [10.0]
    clock[0] = 1000.0
    assert not watch.expired() and said == [10.0]  # once per spell, and waiting for ever
    client.n_workers = 1
    assert not watch.expired()
    client.n_workers = 0
    clock[0] = 1010.0
    watch.expired()
    clock[0] = 1020.0
    assert not watch.expired() and said == [10.0, 10.0]  # a new spell is said again


def test_a_timeout_ends_the_spell_and_a_lost_scheduler_is_not_a_spell(clock):
    client, said = _Client(), []
    client.n_workers = 0
    watch = driver._NoWorkerWatch(client, 10.0, 4.0, said.append)
    assert not watch.expired()
    clock[0] = 104.0
    assert watch.expired() and said == [4.0]  # said at the timeout when it comes before the notice
    client.status = "connecting"
    other = driver._NoWorkerWatch(client, 10.0, 4.0, said.append)
    clock[0] = 200.0
    assert not other.expired()


def _row(key, status):
    return {"key": key, "scenario": "q.toml", "seed": 1, "wall_s": 1.0, "status": status,
            "error": None if status == "ok" else f"{status}: why"}


def test_resume_keeps_ok_and_failed_rows_and_drops_lost_ones(tmp_path):
    # d: a task the cluster dropped, as tables written before the lost status said it
    old = {**_row("d", "failed"), "error": "cancelled: the cluster dropped this task"}
    rows = [_row("a", "ok"), _row("b", "failed"), _row("c", "lost"), old]
    _write_parquet(rows, str(tmp_path / "results.parquet"))
    assert ResultsTable(str(tmp_path), resume=True).done == {"a", "b"}
    assert ResultsTable(str(tmp_path), resume=True, retry_failed=True).done == {"a"}


def test_the_size_of_a_plan_is_counted_without_planning_it():
    head = 'scenarios = ["default"]\nseeds = [1, 2, 3]\n'
    grid = parse_sweep(head + '[axes]\n"controller.kp" = { min = 0.1, max = 1.0, n = 101 }\n'
                       '"controller.ki" = [1.0, 2.0]\n')
    assert planned_runs(grid) == 101 * 2 * 3
    lhs = parse_sweep(head + 'design = "lhs"\nsamples = 7\n'
                      '[axes]\n"controller.kp" = { min = 0.1, max = 1.0 }\n')
    assert planned_runs(lhs) == 7 * 3


def test_the_clients_gather_ended_by_its_close_is_not_printed_but_other_task_errors_are():
    """A result asked with a timeout leaves the client's gather behind; the client's close ends it with
    `AllExit`, and asyncio would print "Task exception was never retrieved" with its traceback on the
    sweep's stderr (seen on a clean clone's run): the remote client's quiet drops that one record."""
    import logging

    from distributed.client import AllExit

    def record(error):
        return logging.LogRecord("asyncio", logging.ERROR, __file__, 1, "Task exception was never retrieved",
                                 None, (type(error), error, None))

    with driver._quiet_dask():
        pass
    log = logging.getLogger("asyncio")
    assert not log.filter(record(AllExit()))
    assert log.filter(record(ValueError("a task's own error")))
