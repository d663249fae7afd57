"""The Dask driver: open a client on an embedded or existing cluster, run tasks, stream results.

Why Dask (`dask.distributed`): its embedded `LocalCluster` needs nothing but pip, and the same code
reaches a real cluster by its scheduler's address. libsumo allows one simulation per process, so the
embedded cluster has one process per worker and one thread each.

Retries: a task that raises is run once more (``retries=1``); a worker that dies running a task gets
the task rescheduled once (the embedded scheduler's ``allowed_failures=1``; an existing cluster
applies its own ``distributed.scheduler.allowed-failures``, 3 by default); after that the task is
reported lost (`KilledWorker`) and the rest go on.

Failed or lost: a task that raised its own exception *failed* (run it again and it fails again); a
task the cluster dropped is *lost* (cancelled, its scheduler gone, its worker dead, a broken
connection): nothing is known about it, and running it again may well succeed.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar

from vrsim.common import ClusterError

T = TypeVar("T")

TASK_RETRIES = 1  # a task that raises runs once more
ALLOWED_FAILURES = 1  # embedded cluster: a task whose worker died is rescheduled once
# Embedded cluster: a worker holds only the task it runs (Dask's default 1.1 queues a second one on a
# one-thread worker), so a worker's death counts against that task alone, and a run of seconds loses
# nothing by not being prefetched.
WORKER_SATURATION = 1.0
CONNECT_TIMEOUT_S = 10.0
NO_WORKER_NOTICE_S = 10.0  # a cluster without a worker this long is said so (`run_tasks`)
_POLL_S = 0.2  # how often `run_tasks` looks for finished tasks and at the cluster's workers
_RESULT_WAIT_S = 2.0  # longest wait for a finished task's result before `run_tasks` looks around again


DASHBOARD_ADDRESS = "127.0.0.1:8787"


def dashboard_available() -> bool:
    """True if bokeh, which Dask's dashboard needs, is installed here."""
    return importlib.util.find_spec("bokeh") is not None


def check_workers(workers: int | None) -> None:
    """Refuse a worker count below one (None: the machine's cores)."""
    if workers is not None and workers < 1:
        raise ClusterError(f"--workers must be >= 1, got {workers}")


@contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None, dashboard: bool = False,
                timeout_s: float = CONNECT_TIMEOUT_S) -> Iterator[Any]:
    """A `distributed.Client` on an existing cluster (`scheduler`) or on an embedded `LocalCluster`.

    Parameters
    ----------
    scheduler : str, optional
        An existing scheduler's address (``tcp://host:8786``); None starts an embedded cluster on
        127.0.0.1 that is closed on exit.
    workers : int, optional
        Worker processes of the embedded cluster (one thread each); default: the machine's cores.
    dashboard : bool
        Serve the embedded cluster's dashboard on `DASHBOARD_ADDRESS` (another free port if that one
        is taken; needs bokeh). Without it the scheduler's small HTTP server (health, metrics) takes a
        free port on 127.0.0.1.
    timeout_s : float
        How long to wait for the scheduler to answer and for a first worker, s.

    Raises
    ------
    ClusterError
        `workers` < 1, or the scheduler does not answer, or no worker joins it within `timeout_s`.
    """
    from distributed import Client

    check_workers(workers)
    if scheduler is None:
        with _local_cluster(workers or os.cpu_count() or 1, dashboard) as cluster, Client(cluster) as client:
            yield client
        return
    with _quiet_dask():
        yield from _remote_client(Client, scheduler, timeout_s)


def _client_shutdown_noise(record: logging.LogRecord) -> bool:
    """False for asyncio's "Task exception was never retrieved" about the client's own gather ending
    with `AllExit` as the client closes: a result asked with a timeout that ran out (`_outcome`) leaves
    that gather behind, and the close ends it; nothing was lost that the rows do not say."""
    error = record.exc_info[1] if record.exc_info else None
    return type(error).__name__ != "AllExit"


@contextmanager
def _quiet_dask():
    """Dask's own log quiet (as the embedded cluster's `silence_logs`): a lost scheduler is the rows'
    `lost` and the command's one line, not the client's tracebacks of each reconnection, nor asyncio's
    word on the client's gather ended by its close (`_client_shutdown_noise`; it may come after the
    close, when the task is collected, so the filter stays)."""
    asyncio_log = logging.getLogger("asyncio")
    if _client_shutdown_noise not in asyncio_log.filters:
        asyncio_log.addFilter(_client_shutdown_noise)
    # Dask's logging config gives its client's logger a level of its own: the package's is not enough.
    logs = [logging.getLogger(name) for name in ("distributed", "distributed.client")]
    levels = [log.level for log in logs]
    for log in logs:
        log.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for log, level in zip(logs, levels, strict=True):
            log.setLevel(level)


CLOSE_TIMEOUT_S = 5.0  # s: how long a client on an existing scheduler may take to close


def _remote_client(Client, scheduler: str, timeout_s: float) -> Iterator[Any]:
    """`open_client`'s client on an existing scheduler (see there)."""
    try:
        client = Client(scheduler, timeout=f"{timeout_s}s")
    except (ValueError, TypeError) as exc:
        raise ClusterError(f"--scheduler {scheduler}: not an address like tcp://host:8786 ({exc})") from None
    except (OSError, TimeoutError) as exc:
        raise ClusterError(f"--scheduler {scheduler}: no answer within {timeout_s:g} s ({exc})") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except TimeoutError:
            raise ClusterError(f"--scheduler {scheduler}: no worker joined within {timeout_s:g} s") from None
        yield client
    finally:
        # Bounded: with its scheduler gone the client is still reconnecting, and an unbounded close
        # waits for that (twice the connect timeout) before the sweep can report its lost rows.
        try:
            client.close(timeout=CLOSE_TIMEOUT_S)
        except (TimeoutError, OSError):
            pass


def _local_cluster(workers: int, dashboard: bool):
    """The embedded cluster: `workers` processes of one thread on 127.0.0.1."""
    import dask
    from distributed import LocalCluster

    http = {"dashboard": dashboard, "dashboard_address": DASHBOARD_ADDRESS if dashboard else "127.0.0.1:0"}
    with dask.config.set({"distributed.scheduler.worker-saturation": WORKER_SATURATION}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            scheduler_port=0, worker_dashboard_address=None, silence_logs=logging.CRITICAL,
                            scheduler_kwargs={"allowed_failures": ALLOWED_FAILURES, **http})


def _describe_failure(exc: BaseException) -> str:
    """A task's exception as one line for its failed row."""
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        return (f"lost: worker died while running this task ({exc.allowed_failures + 1} attempts); "
                f"KilledWorker on {exc.last_worker.address}")
    return f"{type(exc).__name__}: {exc}"


def _outcome(future, wait_s: float = _RESULT_WAIT_S) -> tuple[Any, str | None, bool] | None:
    """(result, error, lost) of a finished future, or None if its result did not come within `wait_s`:
    a result held by a worker that died since is recomputed, which needs a worker (`run_tasks` asks
    again, and watches the cluster meanwhile). `lost` when the cluster dropped the task rather than
    the task raising its own exception (then `future.status` is ``"error"``, `KilledWorker` aside)."""
    from distributed import KilledWorker

    cancelled = None, "lost: the cluster cancelled this task (its scheduler gone, or the link lost)", True
    if future.status == "cancelled":
        return cancelled
    try:
        return future.result(timeout=wait_s), None, False
    except Exception as exc:  # any failure of the task becomes its row's error
        status = future.status
        if isinstance(exc, TimeoutError) and status != "error":  # not the task's own TimeoutError
            return cancelled if status == "cancelled" else None
        own = status == "error" and not isinstance(exc, KilledWorker)
        error = _describe_failure(exc)
        return None, error if own or error.startswith("lost: ") else f"lost: {error}", not own


class _NoWorkerWatch:
    """Tells how long a cluster has had no worker: `say(seconds)` once, `notice_s` into each spell
    without one; `expired` once `timeout_s` (None: never) has passed."""

    def __init__(self, client, notice_s: float, timeout_s: float | None, say: Callable[[float], None]):
        self.client, self.notice_s, self.timeout_s, self.say = client, notice_s, timeout_s, say
        self.since: float | None = None
        self.said = False

    def expired(self) -> bool:
        # The client refreshes the scheduler's identity every 2 s; a client that lost its scheduler
        # has had its tasks cancelled already, which `run_tasks` reports as lost.
        info = self.client.scheduler_info() if self.client.status == "running" else None
        if info is None or info.get("n_workers", len(info.get("workers", {}))) > 0:
            self.since, self.said = None, False
            return False
        now = time.monotonic()
        self.since = now if self.since is None else self.since
        idle_s = now - self.since
        if not self.said and idle_s >= min(self.notice_s, self.timeout_s or self.notice_s):
            self.say(idle_s)
            self.said = True
        return self.timeout_s is not None and idle_s >= self.timeout_s


def run_tasks(client, items: Sequence[T], task: Callable[[T], Any], key: Callable[[T], str],
              on_done: Callable[[T, Any, str | None, bool], None], retries: int = TASK_RETRIES,
              no_worker_timeout_s: float | None = None, on_no_worker: Callable[[float], None] | None = None,
              no_worker_notice_s: float = NO_WORKER_NOTICE_S) -> None:
    """Run ``task(item)`` for every item on the cluster; call ``on_done(item, result, error, lost)`` in
    this process as each finishes, in the order they finish (`distributed.as_completed`).

    A task that raised (twice) comes back with ``result=None``, `error` its one-line description and
    ``lost=False``; one the cluster dropped (cancelled, scheduler gone, its worker died twice, a
    broken connection) with ``lost=True`` and an error starting ``"lost: "``. The others keep running.

    Parameters
    ----------
    client : distributed.Client
    items : sequence
        Plain data; each is pickled to a worker.
    task : callable
        A module-level function (importable on the workers) of one item.
    key : callable
        The task's Dask key for an item (unique within the batch).
    on_done : callable
        Gets each item, its result (or None), its error (or None) and whether it was lost.
    retries : int
        Extra runs of a task that raises.
    no_worker_timeout_s : float, optional
        With no worker on the cluster this long, s, the tasks not done are cancelled and come back
        lost; None waits for a worker however long it takes.
    on_no_worker : callable, optional
        ``on_no_worker(seconds)``, once per spell without a worker, after `no_worker_notice_s` (or
        `no_worker_timeout_s` if shorter).
    no_worker_notice_s : float
        See `on_no_worker`, s.
    """
    from distributed import as_completed

    futures = {client.submit(task, item, key=key(item), retries=retries, pure=False): item
               for item in items}
    watch = _NoWorkerWatch(client, no_worker_notice_s, no_worker_timeout_s, on_no_worker or (lambda s: None))
    done = as_completed(list(futures))
    waiting: list = []  # finished, but their results are being recomputed: asked again as they finish
    while futures:
        ready = done.next_batch(block=False) if done.has_ready() else []
        ready += [f for f in waiting if f.done()]
        waiting = [f for f in waiting if f not in ready]
        for future in ready:
            outcome = _outcome(future)
            if outcome is None:
                waiting.append(future)
                continue
            item = futures.pop(future)
            future.release()
            on_done(item, *outcome)
        if not ready or all(f in waiting for f in ready):
            if watch.expired():
                break
            time.sleep(_POLL_S)
    if not futures:
        return
    client.cancel(list(futures))  # left by a cluster without a worker: cancelled, reported lost
    for item in futures.values():
        on_done(item, None, f"lost: no worker on the cluster for {no_worker_timeout_s:g} s", True)
