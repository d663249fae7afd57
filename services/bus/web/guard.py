"""The page's door: how many connections the web service keeps open, how long one may take to ask,
and what the HTTP server answers on its own (docs/security.md, "Connections").

uvicorn 0.54 bounds neither count nor time before a first request: its keep-alive timer starts only
after a response, so a connection that never sends a byte stays open for ever, and its
``limit_concurrency`` counts such connections but acts only on a request, answering *that* 503
(a crowd of idle connections locks the real ones out) without the page's security headers. So:

- `Listener` is the listening socket; asyncio's accept loop calls its ``accept``, which admits each
  connection through the `Door` before any protocol or TLS handshake exists for it. At most ``cap``
  are open (kept well below the process's file limit, so accept never meets EMFILE); beyond that the
  oldest connection that is waiting for a request head is closed to make room, and only when every
  open connection is in the middle of a request is the new one answered 503 and closed. A host
  beyond loopback may hold at most ``per_host`` (on loopback every local user is 127.0.0.1: a
  per-address cap there would cap the operator with the crowd).
- `Door.sweep` closes a connection that has not sent a whole request head `HEAD_TIMEOUT_S` after it
  came (the TLS handshake included) or after its previous answer, and one whose body has not all
  come `BODY_TIMEOUT_S` after its head.
- `_protocol_class` is uvicorn's h11 protocol telling the door where each connection is; its own 400
  (a head h11 refuses, e.g. two Host headers) carries the security headers.
- What the door closed, accept errors and uvicorn's per-request warnings are logged as one line per
  `LOG_INTERVAL_S` at most, never a line (or a traceback) per event.
"""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import logging
import resource
import socket
import sys
import time
from collections import OrderedDict

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from vrsim.services.bus.web.auth import SECURITY_HEADERS

MAX_CONNECTIONS = 1024  # open at once, TLS handshakes included
RESERVE_FDS = 512  # the process's other files (zenoh, threads, the files it reads) below its limit
PER_HOST_SHARE = 4  # a host beyond loopback may hold cap / 4 connections
HEAD_TIMEOUT_S = 10.0  # from accept (or the previous answer) to a whole request head
BODY_TIMEOUT_S = 60.0  # from the head to the end of its body (a 1 MB scenario at 17 KB/s)
KEEP_ALIVE_S = 5  # uvicorn's: an idle connection after an answer
MAX_HEAD_BYTES = 16384  # h11's cap on a request head (uvicorn answers 400 beyond)
BACKLOG = 128  # the listen queue, and how many connections asyncio accepts per wake-up
SWEEP_S = 1.0
LOG_INTERVAL_S = 60.0
WAITING, RECEIVING, SERVING = "waiting", "receiving", "serving"  # for a head, for a body, answering

_BUSY_BODY = b"too many connections: try again in a few seconds\n"
BUSY = (b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: text/plain; charset=utf-8\r\n"
        b"retry-after: 5\r\nconnection: close\r\n"
        + b"".join(name + b": " + value + b"\r\n" for name, value in SECURITY_HEADERS)
        + b"content-length: %d\r\n\r\n" % len(_BUSY_BODY) + _BUSY_BODY)


def raise_file_limit() -> int:
    """Raise this process's soft limit on open files to its hard limit (a crowd of connections is
    closed by the door well before either); returns the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return 1 << 20
    want = hard if hard != resource.RLIM_INFINITY else max(soft, 65536)
    if soft < want:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
            soft = want
        except (ValueError, OSError):
            pass  # a container may refuse: the cap below follows the limit as it is
    return soft


def cap_for(file_limit: int) -> int:
    """Connections the door keeps open under ``file_limit`` open files."""
    return max(16, min(MAX_CONNECTIONS, file_limit - RESERVE_FDS))


def _loopback(host: str) -> bool:
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return False
    mapped = getattr(address, "ipv4_mapped", None)
    return (mapped or address).is_loopback


class _Entry:
    """One open connection: its socket, peer host, where it is (`WAITING`, ...) and since when."""

    __slots__ = ("sock", "fd", "host", "state", "since")

    def __init__(self, sock: socket.socket, host: str):
        self.sock, self.fd, self.host = sock, sock.fileno(), host
        self.state, self.since = WAITING, time.monotonic()


class Door:
    """The open connections of one server, oldest first, and what was done to them.

    Parameters
    ----------
    cap : int
        Connections open at once at most.
    tls : bool
        Connections speak TLS (one refused is closed without a plain-text 503).
    head_timeout_s, body_timeout_s : float
        See `HEAD_TIMEOUT_S`, `BODY_TIMEOUT_S`.
    """

    def __init__(self, cap: int, tls: bool = False, head_timeout_s: float = HEAD_TIMEOUT_S,
                 body_timeout_s: float = BODY_TIMEOUT_S):
        self.cap, self.per_host, self.tls = cap, max(1, cap // PER_HOST_SHARE), tls
        self.head_timeout_s, self.body_timeout_s = head_timeout_s, body_timeout_s
        self.entries: OrderedDict[int, _Entry] = OrderedDict()  # by file descriptor
        self.hosts: dict[str, int] = {}
        self.counts: dict[str, int] = {}  # what happened since the last line logged
        self.logged_s = -LOG_INTERVAL_S  # the first happening is logged at once
        self.peak = 0

    # ---------------------------------------------------------------- accept
    def admit(self, conn: socket.socket, addr) -> bool:
        """Keep ``conn`` (True), or answer it 503 and close it (False)."""
        host = addr[0] if isinstance(addr, tuple) else ""
        refused = self._refusal(host)
        if refused is not None:
            self.count(refused + ("" if self.tls else " (503)"))
            if not self.tls:
                try:
                    conn.send(BUSY)
                except OSError:
                    pass
            conn.close()
            return False
        entry = _Entry(conn, host)
        stale = self.entries.pop(entry.fd, None)  # its descriptor was closed and reused
        if stale is not None:
            self._uncount(stale)
        self.entries[entry.fd] = entry
        self.hosts[host] = self.hosts.get(host, 0) + 1
        self.peak = max(self.peak, len(self.entries))
        return True

    def _refusal(self, host: str) -> str | None:
        """Why another connection of ``host`` finds no room, even after closing a waiting one (None:
        it has room)."""
        limited = not _loopback(host)
        if len(self.entries) >= self.cap or (limited and self.hosts.get(host, 0) >= self.per_host):
            self._prune()
        if limited and self.hosts.get(host, 0) >= self.per_host:
            return f"refused: {self.per_host} open from one address"
        if len(self.entries) >= self.cap and not self._evict():
            return f"refused: all {self.cap} in a request"
        return None

    def _evict(self) -> bool:
        """Close the oldest connection waiting for a request head (an idle one costs its client only a
        reconnect; one in a request is never cut)."""
        for entry in self.entries.values():
            if entry.state == WAITING:
                self._close(entry)
                self.count("closed to make room (the oldest idle)")
                return True
        return False

    def _prune(self) -> None:
        """Forget connections their transports closed (a failed TLS handshake tells no protocol)."""
        for entry in [e for e in self.entries.values() if e.sock.fileno() == -1]:
            self.forget(entry)

    # ---------------------------------------------------------------- the protocol's side
    def entry_of(self, transport) -> _Entry | None:
        sock = transport.get_extra_info("socket")
        return self.entries.get(sock.fileno()) if sock is not None else None

    def mark(self, entry: _Entry | None, state: str) -> None:
        """``entry`` is now ``state``; its deadline runs from the change."""
        if entry is None or entry.state == state:
            return
        entry.state, entry.since = state, time.monotonic()
        if state == WAITING and self.entries.get(entry.fd) is entry:
            self.entries.move_to_end(entry.fd)  # idle again: the last to make room

    def forget(self, entry: _Entry | None) -> None:
        if entry is not None and self.entries.get(entry.fd) is entry:
            del self.entries[entry.fd]
            self._uncount(entry)

    def _uncount(self, entry: _Entry) -> None:
        left = self.hosts.get(entry.host, 1) - 1
        if left:
            self.hosts[entry.host] = left
        else:
            self.hosts.pop(entry.host, None)

    def _close(self, entry: _Entry) -> None:
        """Shut ``entry``'s socket: its transport reads the end and closes it the usual way (closing the
        descriptor under the transport would let the number be reused while asyncio still watches it)."""
        try:
            entry.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.forget(entry)

    # ---------------------------------------------------------------- deadlines and the log
    async def sweep(self) -> None:
        """Every `SWEEP_S`: close connections past their deadline; log what happened, at most once per
        `LOG_INTERVAL_S`."""
        while True:
            await asyncio.sleep(SWEEP_S)
            self.expire(time.monotonic())
            self.report(time.monotonic())

    def expire(self, now: float) -> None:
        for entry in list(self.entries.values()):
            if entry.sock.fileno() == -1:
                self.forget(entry)
            elif entry.state == WAITING and now - entry.since > self.head_timeout_s:
                self._close(entry)
                self.count(f"closed: no request head within {self.head_timeout_s:g} s")
            elif entry.state == RECEIVING and now - entry.since > self.body_timeout_s:
                self._close(entry)
                self.count(f"closed: no whole body within {self.body_timeout_s:g} s")

    def count(self, what: str) -> None:
        self.counts[what] = self.counts.get(what, 0) + 1

    def report(self, now: float) -> None:
        if not self.counts or now - self.logged_s < LOG_INTERVAL_S:
            return
        told = "; ".join(f"{what}: {n}" for what, n in self.counts.items())
        print(f"vrsim serve web: connections: {told} (at most {self.cap} open, {self.peak} at the peak; "
              f"one line a minute at most)", file=sys.stderr, flush=True)
        self.counts, self.logged_s, self.peak = {}, now, len(self.entries)

    def loop_exception(self, loop, context: dict) -> None:
        """asyncio's exception handler: an accept that failed for want of resources (EMFILE, ...) is
        counted, not logged with its traceback on every retry; anything else as asyncio would."""
        exc = context.get("exception")
        if context.get("message", "").startswith("socket.accept() out of system resource"):
            code = errno.errorcode.get(getattr(exc, "errno", None) or 0, str(exc))
            self.count(f"accept failed ({code}, retried each second)")
            return
        loop.default_exception_handler(context)

    def log_filter(self, record: logging.LogRecord) -> bool:
        """For uvicorn's logger: a warning it logs per request ("Invalid HTTP request received.",
        "Unsupported upgrade request.") is counted, not written each time."""
        if record.levelno != logging.WARNING:
            return True
        self.count(f"uvicorn: {record.getMessage().split('. ')[0][:80]}")  # its first sentence
        return False


class Listener(socket.socket):
    """A listening socket whose ``accept`` (what asyncio's accept loop calls) admits connections
    through ``door``: a refused one is answered and closed here, and the next one taken."""

    door: Door | None = None

    def accept(self):
        while True:
            conn, addr = super().accept()  # BlockingIOError when none is waiting: asyncio's cue to stop
            if self.door is None or self.door.admit(conn, addr):
                return conn, addr


class _GuardedH11(H11Protocol):
    """uvicorn's h11 protocol, telling its `Door` whether it waits for a head, a body, or answers."""

    door: Door
    entry: _Entry | None = None

    def connection_made(self, transport) -> None:
        super().connection_made(transport)
        self.entry = self.door.entry_of(transport)

    def connection_lost(self, exc) -> None:
        super().connection_lost(exc)
        self.door.forget(self.entry)

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._mark()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._mark()

    def _mark(self) -> None:
        their = self.conn.their_state
        self.door.mark(self.entry, WAITING if their is h11.IDLE else RECEIVING if their is h11.SEND_BODY
                       else SERVING)

    def send_400_response(self, msg: str) -> None:
        """uvicorn's 400 for a head h11 refuses, with the page's security headers."""
        headers = [(b"content-type", b"text/plain; charset=utf-8"), (b"connection", b"close"),
                   *SECURITY_HEADERS]
        for event in (h11.Response(status_code=400, headers=headers, reason=b"Bad Request"),
                      h11.Data(data=msg.encode("ascii")), h11.EndOfMessage()):
            self.transport.write(self.conn.send(event))
        self.transport.close()


def _protocol_class(door: Door) -> type:
    """The protocol class uvicorn builds per connection (``Config(http=...)``), bound to ``door``."""
    return type("GuardedH11Protocol", (_GuardedH11,), {"door": door})


class Server(uvicorn.Server):
    """uvicorn's server with the door's sweep running, and accept errors counted by the door."""

    def __init__(self, config: uvicorn.Config, door: Door):
        super().__init__(config)
        self.door = door
        self.sweeper: asyncio.Task | None = None

    async def startup(self, sockets=None) -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(self.door.loop_exception)
        self.sweeper = loop.create_task(self.door.sweep())
        await super().startup(sockets=sockets)

    async def shutdown(self, sockets=None) -> None:
        if self.sweeper is not None:
            self.sweeper.cancel()
        await super().shutdown(sockets=sockets)


def config(app, door: Door, tls: tuple[str, str] | None) -> uvicorn.Config:
    """uvicorn's configuration for the page behind ``door``. No ``limit_concurrency``: the door caps
    connections at accept and makes room among idle ones, where uvicorn's would answer a real
    request 503 while idle connections fill the count (and without the security headers); no
    WebSocket (an upgrade is answered by the app, as plain HTTP)."""
    certfile, keyfile = tls or (None, None)
    return uvicorn.Config(app, log_level="warning", access_log=False, timeout_graceful_shutdown=1,
                          lifespan="on", ssl_certfile=certfile, ssl_keyfile=keyfile,
                          http=_protocol_class(door), ws="none", backlog=BACKLOG,
                          timeout_keep_alive=KEEP_ALIVE_S, h11_max_incomplete_event_size=MAX_HEAD_BYTES)
