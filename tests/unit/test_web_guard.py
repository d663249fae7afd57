"""The page's door (services/bus/web/guard.py, issue #41) with the real uvicorn and real sockets on
127.0.0.1, in this process and with a small door (a few connections, deadlines of a second or two):
idle connections beyond the cap make room and are closed after the head deadline while the page
answers; a body that does not come is cut; a crowd in the middle of requests gets 503; every answer
the server makes itself carries the security headers; what happens is logged once, not per event.
The same with the real `vrsim serve web` and its real cap: tests/integration/test_web_doors.py."""

from __future__ import annotations

import contextlib
import errno
import http.client
import socket
import threading
import time

import pytest

from tests.unit.test_web_auth import PASSWORDS, FakeOperator, NoBus
from vrsim.services.bus.web import _allowed_hosts, _bind, _HttpServer, guard
from vrsim.services.bus.web.app import create_app
from vrsim.services.bus.web.auth import Logins
from vrsim.services.bus.web.live import LiveView

HEAD_S = 1.5  # the small door's deadlines
WAIT_S = 20.0  # generous: the machine is shared


@contextlib.contextmanager
def served(cap: int):
    """The page on a free port behind a `guard.Door` of ``cap`` connections: (port, logins, door)."""
    logins = Logins("operator", PASSWORDS, "vrsim_session_8448")
    app = create_app(LiveView(), NoBus(), FakeOperator(), logins, _allowed_hosts("127.0.0.1"))
    sock = _bind("127.0.0.1", 0)
    door = guard.Door(cap, head_timeout_s=HEAD_S, body_timeout_s=HEAD_S)
    http = _HttpServer(app, sock, threading.Event(), door=door)
    try:
        yield sock.getsockname()[1], logins, door
    finally:
        http.close()
        sock.close()


def connect(port: int) -> socket.socket:
    return socket.create_connection(("127.0.0.1", port), timeout=10)


def closed_by_server(sock: socket.socket) -> bool:
    """The server ended this connection (it reads the end, or a reset); False while it is open."""
    sock.settimeout(0)  # look, never wait
    try:
        return sock.recv(65536, socket.MSG_PEEK) == b"" or _drained(sock)
    except BlockingIOError:
        return False
    except OSError:
        return True


def _drained(sock: socket.socket) -> bool:
    """An answer is waiting before the end: read it, then look again."""
    sock.recv(65536)
    return closed_by_server(sock)


def until(condition, timeout_s: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "not within the deadline"
        time.sleep(0.05)


def raw(port: int, request: bytes) -> bytes:
    """The whole answer to ``request`` (the server closes after it)."""
    with connect(port) as sock:
        sock.sendall(request)
        out = b""
        while chunk := sock.recv(65536):
            out += chunk
    return out


def login_page(port: int) -> int:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=WAIT_S)
    try:
        conn.request("GET", "/login")
        return conn.getresponse().status
    finally:
        conn.close()


def test_idle_connections_beyond_the_cap_make_room_and_go_after_the_head_deadline():
    with served(cap=8) as (port, _, door):
        idle = [connect(port) for _ in range(40)]
        try:
            assert login_page(port) == 200  # the oldest idle one made room for it
            until(lambda: sum(map(closed_by_server, idle)) >= 40 - 8)
            assert len(door.entries) <= 8
            until(lambda: all(map(closed_by_server, idle)), HEAD_S + WAIT_S)  # the rest: the deadline
            assert door.entries == {} or all(e.sock.fileno() == -1 for e in door.entries.values())
        finally:
            for sock in idle:
                sock.close()


def test_half_a_head_is_closed_after_the_deadline_and_not_before():
    with served(cap=8) as (port, _, _):
        with connect(port) as sock:
            sock.sendall(b"GET /login HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # and never the blank line
            time.sleep(HEAD_S / 3)
            assert not closed_by_server(sock)
            until(lambda: closed_by_server(sock), HEAD_S + WAIT_S)


def test_a_body_that_does_not_come_is_cut():
    with served(cap=8) as (port, _, _):
        with connect(port) as sock:
            sock.sendall(b"POST /login HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000\r\n"
                         b"Content-Type: application/x-www-form-urlencoded\r\n\r\nuser=viewe")
            until(lambda: closed_by_server(sock), HEAD_S + WAIT_S)


def test_when_every_connection_is_in_a_request_a_new_one_gets_503_with_the_security_headers():
    with served(cap=3) as (port, logins, _):
        sid = logins.open("viewer")
        ask = (f"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\nCookie: {logins.cookie}={sid}\r\n"
               f"X-Vrsim-Key: {logins.sessions[sid].key}\r\n\r\n").encode()
        streams = [connect(port) for _ in range(3)]
        try:
            for sock in streams:
                sock.sendall(ask)
                assert sock.recv(12) == b"HTTP/1.1 200"
            answer = raw(port, b"")  # nothing asked: the door answers at once
            assert answer.startswith(b"HTTP/1.1 503") and b"\r\nretry-after: 5\r\n" in answer
            assert b"\r\nx-frame-options: DENY\r\n" in answer and b"frame-ancestors 'none'" in answer
        finally:
            for sock in streams:
                sock.close()
        until(lambda: login_page(port) == 200)


@pytest.mark.parametrize("request_bytes", [
    b"GET /login HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n",  # two Host headers
    b"GET /login HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"x" * 20000,  # 16 KB buffered, no end yet
    b"GET /login HTTP/1.1\r\n\r\n",  # no Host
])
def test_uvicorns_own_400_carries_the_security_headers(request_bytes):
    with served(cap=8) as (port, _, _):
        answer = raw(port, request_bytes)
    assert answer.startswith(b"HTTP/1.1 400")
    head = answer.split(b"\r\n\r\n")[0].lower()
    for name in (b"x-frame-options: deny", b"content-security-policy: default-src 'self'",
                 b"x-content-type-options: nosniff", b"referrer-policy: same-origin"):
        assert name in head, name


def test_per_request_warnings_and_closed_connections_are_logged_once(capfd):
    with served(cap=4) as (port, _, door):
        for _ in range(30):
            bad = raw(port, b"GET /login HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: x\r\n\r\n")
            upgrade = raw(port, b"GET /login HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: Upgrade, close\r\n"
                                b"Upgrade: websocket\r\n\r\n")  # no WebSocket here: the app answers
            assert bad.startswith(b"HTTP/1.1 400") and upgrade.startswith(b"HTTP/1.1 200")
            assert b"x-frame-options: DENY" in upgrade
        idle = [connect(port) for _ in range(20)]
        until(lambda: sum(map(closed_by_server, idle)) >= 16)
        for sock in idle:
            sock.close()
        until(lambda: door.logged_s > 0)  # its first line
    lines = capfd.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("vrsim serve web: connections:"), lines  # one line in all
    for counted in ("uvicorn: Invalid HTTP request received.: 30",
                    "uvicorn: Unsupported upgrade request.: 30", "closed to make room (the oldest idle): 16"):
        assert counted in lines[0]


def test_accept_errors_are_counted_and_logged_once_a_minute_without_a_traceback(capsys):
    door = guard.Door(8)
    emfile = {"message": "socket.accept() out of system resource",
              "exception": OSError(errno.EMFILE, "Too many open files")}
    for _ in range(1000):
        door.loop_exception(None, emfile)  # what asyncio does on every retry
    door.report(100.0)
    for _ in range(1000):
        door.loop_exception(None, emfile)
    door.report(100.0 + guard.LOG_INTERVAL_S / 2)  # within the minute: nothing
    first = capsys.readouterr().err
    door.report(100.0 + guard.LOG_INTERVAL_S)
    second = capsys.readouterr().err
    assert first.count("\n") == 1 and "accept failed (EMFILE, retried each second): 1000" in first
    assert "Traceback" not in first
    assert second.count("\n") == 1 and ": 1000" in second


def test_the_file_limit_is_raised_and_the_cap_stays_well_below_it():
    import resource

    limit = guard.raise_file_limit()
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    assert limit == soft and (soft == hard or hard == resource.RLIM_INFINITY)
    assert guard.cap_for(20000) == guard.MAX_CONNECTIONS == 1024
    assert guard.cap_for(1024) == 512 and guard.cap_for(100) == 16
