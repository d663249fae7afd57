"""The web page's third round of trust (issue #41), with real processes: `vrsim serve all --web` and
a `vrsim serve web` of its own (its log a file of its own), and a real Chromium.

- A crowd of idle connections, more than the door keeps (services/bus/web/guard.py), neither locks
  the page out nor floods its log: ``/login`` answers while they are held, the server closes them
  (the oldest at once to make room, the rest after the head deadline), and the log grows by a line.
- The session cookie a lured browser hands a server on another port of 127.0.0.1 is no login there:
  replayed alone it gets 401 on ``/api/view``, ``/api/stop`` and ``/events``; with the page's key
  (which the browser never sent there) it works.
"""

from __future__ import annotations

import http.client
import http.server
import json
import os
import resource
import socket
import threading
import time

import pytest

from tests.integration.test_web import (
    CHROMIUM,
    CHROMIUM_ARGS,
    need_chromium,
    open_page,
    serve_viewer,
    served_web,
    until,
)
from vrsim.services.bus.web.guard import HEAD_TIMEOUT_S, MAX_CONNECTIONS

CROWD = MAX_CONNECTIONS + 476  # idle connections, more than the door keeps (1,500)
LOGIN_DEADLINE_S = 60.0  # generous: the machine is shared
LOG_GROWTH_BOUND = 4096  # bytes of the web process's log while the crowd comes and goes


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    with served_web(str(tmp_path_factory.mktemp("webdoors"))) as server:
        yield server


def closed_by_server(sock: socket.socket) -> bool:
    sock.settimeout(0)  # look, never wait
    try:
        return sock.recv(1, socket.MSG_PEEK) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


def soft_hard_files(pid: int) -> tuple[str, str]:
    with open(f"/proc/{pid}/limits") as fh:
        row = next(line for line in fh if line.startswith("Max open files"))
    return tuple(row.split()[3:5])


def test_a_crowd_of_idle_connections_neither_locks_the_page_out_nor_floods_its_log(net):
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = CROWD + 200  # this test's own sockets
    if soft < need:
        if hard != resource.RLIM_INFINITY and hard < need:
            pytest.skip(f"this process may open {hard} files, fewer than the crowd's {CROWD}")
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
    proc, web = serve_viewer(net)
    log = os.path.join(net.folder, f"web-{web.port}.log")
    limits = soft_hard_files(proc.pid)
    assert limits[0] == limits[1], limits  # the web process raised its soft limit to the hard one
    before = os.path.getsize(log)
    crowd: list[socket.socket] = []
    try:
        for _ in range(CROWD):
            crowd.append(socket.create_connection(("127.0.0.1", web.port), timeout=30))
        asked = time.monotonic()
        conn = http.client.HTTPConnection("127.0.0.1", web.port, timeout=LOGIN_DEADLINE_S)
        conn.request("GET", "/login")
        resp = conn.getresponse()
        body = resp.read()
        conn.close()
        answered_s = time.monotonic() - asked
        assert resp.status == 200 and b'name="password"' in body
        held = sum(not closed_by_server(s) for s in crowd)
        assert held <= MAX_CONNECTIONS  # the oldest made room at once
        deadline = time.monotonic() + HEAD_TIMEOUT_S + 30
        while not all(closed_by_server(s) for s in crowd):  # the rest: after the head deadline
            assert time.monotonic() < deadline, f"{sum(not closed_by_server(s) for s in crowd)} still open"
            time.sleep(0.5)
        closed_s = time.monotonic() - asked
    finally:
        for sock in crowd:
            sock.close()
    time.sleep(2.0)  # the door's line for what it closed
    grown = os.path.getsize(log) - before
    with open(log) as fh:
        fh.seek(before)
        said = fh.read()
    print(f"\n{CROWD} idle connections opened ({held} still held by the server when /login was asked): "
          f"/login answered 200 in {answered_s * 1000:.0f} ms; all closed by the server {closed_s:.1f} s "
          f"after; the web log grew {grown} bytes: {said.strip()!r}")
    assert grown < LOG_GROWTH_BOUND and "Traceback" not in said
    assert web.get("/login")[0] == 200


class Trap(http.server.BaseHTTPRequestHandler):
    """Another local user's plain HTTP server: a link from localhost to 127.0.0.1, then a same-host
    navigation (the issue's lure); it keeps every request's line and headers."""

    seen: list[tuple[str, dict]] = []

    def do_GET(self):  # noqa: N802 (http.server's name)
        Trap.seen.append((self.path, dict(self.headers)))
        port = self.server.server_address[1]
        page = {"/": f'<a id="go" href="http://127.0.0.1:{port}/step">on</a>',
                "/step": '<script>location.href = "/got";</script>'}.get(self.path, "thanks")
        body = page.encode()
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:
        pass


def replay(port: int, method: str, path: str, headers: dict) -> int:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        conn.request(method, path, body=b"" if method == "POST" else None, headers=headers)
        resp = conn.getresponse()
        if path != "/events" or resp.status != 200:
            resp.read()
        return resp.status
    finally:
        conn.close()


def test_the_cookie_a_lured_browser_hands_another_port_is_no_login(net):
    need_chromium()
    from playwright.sync_api import sync_playwright

    trap = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Trap)
    threading.Thread(target=trap.serve_forever, daemon=True).start()
    trap_port = trap.server_address[1]
    name = f"vrsim_session_{net.web.port}"
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            try:
                page, errors = open_page(browser, net.web)
                until(page, "window.vrsimView.role === 'operator' && window.vrsimView.connected")
                key = page.evaluate("window.localStorage.getItem('vrsim_key')")
                assert key and errors == []
                page.goto(f"http://localhost:{trap_port}/")  # the lure
                page.click("#go")
                deadline = time.monotonic() + 30
                while not any(path == "/got" for path, _ in Trap.seen):
                    assert time.monotonic() < deadline, Trap.seen
                    time.sleep(0.1)
            finally:
                browser.close()
    finally:
        trap.shutdown()
    got = next(headers for path, headers in Trap.seen if path == "/got")
    cookie = next(c.strip() for c in got.get("Cookie", "").split(";") if c.strip().startswith(name + "="))
    assert all(key not in f"{path} {headers}" for path, headers in Trap.seen)  # the key never left
    # The attacker's replay, with every header a script of theirs could add but the key.
    alone = {"Cookie": cookie, "X-CSRF-Token": "unknown"}
    answers = {path: replay(net.web.port, method, path, alone)
               for method, path in (("GET", "/api/view"), ("POST", "/api/stop"), ("GET", "/events"))}
    print(f"\nthe cookie the lured browser sent to 127.0.0.1:{trap_port}, replayed alone: {answers}")
    assert answers == {"/api/view": 401, "/api/stop": 401, "/events": 401}
    # The page's own requests carry the key: the same cookie with it works.
    both = {"Cookie": cookie, "X-Vrsim-Key": key}
    conn = http.client.HTTPConnection("127.0.0.1", net.web.port, timeout=30)
    conn.request("GET", "/api/view", headers=both)
    resp = conn.getresponse()
    csrf = json.loads(resp.read())["csrf"]
    conn.close()
    assert resp.status == 200
    assert replay(net.web.port, "POST", "/api/stop", {**both, "X-CSRF-Token": csrf}) == 200
    assert replay(net.web.port, "GET", "/events", both) == 200
