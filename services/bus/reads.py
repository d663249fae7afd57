"""The monitor's expensive reads made cheap: the last report of a run kept and answered again while it
still holds (`CachedReport`), and a limit on how often anyone may ask (`RateLimit`).

A report rebuilds the whole run from the database (about a second for the default scenario's 177,002
ticks): a viewer asking for it in a loop would take a core from a lockstep run. The monitor keeps
each run's last report keyed by what it was made from (records stored, announced end), so a finished
run's report is made once; a live run's at most every `REPORT_LIVE_EVERY_S` and at most
`REPORT_LIVE_DUTY` of the time.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from vrsim.common import ServiceError
from vrsim.services.bus.serving import Later

REPORT_LIVE_EVERY_S = 5.0  # a live run's report is rebuilt at most this often ...
REPORT_LIVE_DUTY = 0.025  # ... and at most this share of the time (a 1 s rebuild: every 40 s)
REPORT_RATE_PER_S = 5.0  # report queries a second the monitor answers, over every querier
REPORT_BURST = 10
MAX_CACHED_REPORTS = 1000  # runs whose last report is kept (a few kB each)
REFUSAL_DELAY_S = 0.5  # a refusal is answered this late, so a querier asking in a loop asks slowly
MAX_DELAYED = 16  # refusals waiting at once (a thread each); beyond, they are answered at once


@dataclass(frozen=True)
class CachedReport:
    """A run's last report: ``key`` (records stored, announced end) says what it was made from."""

    key: tuple
    body: bytes
    made_s: float  # time.monotonic() when made
    took_s: float  # how long it took to make

    def fresh(self, key: tuple) -> bool:
        """Whether it still answers for a run now at ``key``: the same records and end, or a live run
        (no end announced) whose report was made less than `REPORT_LIVE_EVERY_S` (or 1 / duty times
        its making) ago: a viewer asking in a loop costs the run at most that share of a core."""
        if key == self.key:
            return True
        live = key[1] is None and self.key[1] is None
        wait_s = max(REPORT_LIVE_EVERY_S, self.took_s / REPORT_LIVE_DUTY)
        return live and time.monotonic() - self.made_s < wait_s


class RateLimit:
    """A token bucket: at most ``rate_per_s`` a second on average, ``burst`` at once.

    Zenoh does not tell a queryable which user asked (a query carries no login, and its source id is
    the querier's to set), so on the bus this is one bucket for every querier of this monitor."""

    def __init__(self, rate_per_s: float, burst: int):
        self.rate_per_s, self.burst = rate_per_s, burst
        self.tokens, self.t = float(burst), time.monotonic()
        self.lock = threading.Lock()
        self.delayed = threading.BoundedSemaphore(MAX_DELAYED)

    def take(self, key: str) -> None:
        """One query's token, or a `ServiceError` saying to ask again later."""
        with self.lock:
            now = time.monotonic()
            self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate_per_s)
            self.t = now
            if self.tokens < 1.0:
                raise ServiceError(f"{key}: too many report queries (at most {self.rate_per_s:g} a second "
                                   f"across all clients, {self.burst} at once); ask again in a moment")
            self.tokens -= 1.0

    def admit(self, key: str) -> Later | None:
        """None when the query may go on (`take`); else a `Later` that answers the refusal after
        `REFUSAL_DELAY_S`: refused at once, a querier in a loop would ask hundreds of times a second
        and take the run's CPU in the router and here instead."""
        try:
            self.take(key)
            return None
        except ServiceError as exc:
            refusal = exc
        if not self.delayed.acquire(blocking=False):
            raise refusal

        def late() -> bytes:
            try:
                time.sleep(REFUSAL_DELAY_S)
            finally:
                self.delayed.release()
            raise refusal

        return Later(late)
