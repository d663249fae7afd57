"""The web page asks who you are (issue #28), with real processes: `vrsim serve all --web` on
loopback and `vrsim serve all --tls --web --web-listen 127.0.0.2:PORT` beyond it. Without a session
nothing answers; a viewer's login cannot start or stop; an operator's needs the CSRF token; every
answer forbids framing; a forged Host is refused on every listen address; beyond loopback the page
is TLS with the bus's CA; at most `MAX_STREAMS` event streams (503 beyond), and a crowd of stream
clients that stop reading neither grows the web process without bound nor keeps its memory after
they leave."""

from __future__ import annotations

import http.client
import os
import socket
import ssl
import subprocess
import time

import psutil
import pytest

from tests.conftest import VRSIM
from tests.integration.test_services_support import ServeAll, free_port
from tests.integration.test_web import (
    CHROMIUM,
    CHROMIUM_ARGS,
    Web,
    need_chromium,
    printed_token,
    served_web,
    until,
)
from vrsim.services.bus.web.app import MAX_STREAMS

CROWD = 300  # stream clients at once in the memory test
PAINT_S = 8.0  # of the built-in default run before the crowd comes
HOLD_S = 6.0
LEFT_S = 5
GROWTH_BOUND_MB = 100  # the web process's RSS over its own baseline while the crowd is there and leaves
LEFT_BOUND_MB = 25  # ... and once it has left
ANSWER_DEADLINE_S = 30.0  # /api/status while the crowd is there (well under 1 s on a quiet machine)


def passwords(state: str) -> dict:
    with open(os.path.join(state, "dictionary.txt")) as fh:
        return dict(line.strip().split(":", 1) for line in fh if ":" in line)


def login(web: Web, user: str, password: str) -> Web:
    """A second client of ``web``'s service logged in with a bus user's password."""
    other = Web(web.port)
    conn = http.client.HTTPConnection("127.0.0.1", web.port, timeout=30)
    try:
        conn.request("POST", "/login", body=f"user={user}&password={password}",
                     headers={"Content-Type": "application/x-www-form-urlencoded"})
        resp = conn.getresponse()
        resp.read()
    finally:
        conn.close()
    other.key = resp.getheader("x-vrsim-key")
    assert resp.status == 303 and resp.getheader("location") == f"/#key={other.key}"
    other.cookie = resp.getheader("set-cookie").split(";")[0]
    other.csrf = other.json("/api/view")["csrf"]
    return other


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    with served_web(str(tmp_path_factory.mktemp("webtrust"))) as server:
        yield server


def test_the_url_printed_at_start_carries_a_token_that_logs_in(net):
    token = printed_token(net.output(), net.web.port)
    assert token is not None and len(token) >= 40
    assert net.web.json("/api/view")["role"] == "operator"


@pytest.mark.parametrize("path", ["/events", "/api/map", "/api/status", "/api/view", "/api/report"])
def test_nothing_answers_without_a_session(net, path):
    anonymous = Web(net.web.port)
    status, body, _ = anonymous.get(path)
    assert status == 401 and b"log in first" in body


def test_the_page_without_a_session_is_the_login_page(net):
    anonymous = Web(net.web.port)
    status, _, _ = anonymous.get("/")
    assert status == 303
    status, body, _ = anonymous.get("/login")
    assert status == 200 and b'name="password"' in body


def test_start_and_stop_need_an_operators_session_and_its_csrf_token(net):
    anonymous = Web(net.web.port)
    for verb in ("start", "stop"):
        assert anonymous.request("POST", f"/api/{verb}", b"")[0] == 401
    users = passwords(net.state)
    viewer = login(net.web, "viewer", users["viewer"])
    status, body, _ = viewer.request("POST", "/api/start", b"")
    assert status == 403 and b"viewer" in body
    operator = login(net.web, "operator", users["operator"])
    operator.csrf = None  # a POST without the token, as another site's form would send
    status, body, _ = operator.request("POST", "/api/stop")
    assert status == 403 and b"X-CSRF-Token" in body
    status, _, _ = anonymous.request("POST", "/login", b"user=viewer&password=wrong",
                                     {"Content-Type": "application/x-www-form-urlencoded"})
    assert status == 401


def test_every_answer_forbids_framing(net):
    anonymous = Web(net.web.port)
    for web, path in ((anonymous, "/"), (anonymous, "/login"), (anonymous, "/api/status"),
                      (net.web, "/"), (net.web, "/api/status"), (net.web, "/static/view.js")):
        conn = http.client.HTTPConnection("127.0.0.1", web.port, timeout=30)
        conn.request("GET", path, headers={"Cookie": web.cookie} if web.cookie else {})
        resp = conn.getresponse()
        resp.read()
        conn.close()
        assert resp.getheader("x-frame-options") == "DENY", path
        assert "frame-ancestors 'none'" in resp.getheader("content-security-policy"), path


def test_in_chromium_the_page_asks_for_a_login_and_a_viewers_password_shows_it_without_buttons(net):
    need_chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            page.goto(net.web.base + "/")
            assert page.url == net.web.base + "/login"
            page.select_option("select[name=user]", "viewer")
            page.fill("input[name=password]", passwords(net.state)["viewer"])
            page.click("button[type=submit]")
            until(page, "window.vrsimView !== undefined && window.vrsimView.role === 'viewer' "
                        "&& window.vrsimView.connected")
            assert page.url == net.web.base + "/"
            assert page.evaluate("document.getElementById('ops').hidden") is True
            cookie = next(c for c in page.context.cookies() if c["name"] == f"vrsim_session_{net.web.port}")
            assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
            assert page.evaluate("document.cookie") == ""  # the page's script cannot read the session
        finally:
            browser.close()


class Client:
    """A raw ``GET /events`` that reads its answer's first line, then reads nothing more."""

    def __init__(self, web: Web):
        self.sock = socket.create_connection(("127.0.0.1", web.port), timeout=30)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.sock.sendall(f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{web.port}\r\nCookie: {web.cookie}\r\n"
                          f"X-Vrsim-Key: {web.key}\r\nAccept: text/event-stream\r\n\r\n".encode())

    def status(self) -> int:
        line = b""
        while not line.endswith(b"\r\n"):
            chunk = self.sock.recv(1)
            if not chunk:
                return 0
            line += chunk
        return int(line.split()[1])

    def close(self) -> None:
        self.sock.close()


def test_event_streams_beyond_the_cap_are_503(net):
    clients = [Client(net.web) for _ in range(MAX_STREAMS)]
    try:
        assert [c.status() for c in clients] == [200] * MAX_STREAMS
        extra = Client(net.web)
        assert extra.status() == 503
        extra.close()
    finally:
        for c in clients:
            c.close()
    deadline = time.monotonic() + 10
    while Client(net.web).status() != 200:  # the closed streams are freed
        assert time.monotonic() < deadline
        time.sleep(0.2)


def rss_mb(pid: int) -> float:
    return psutil.Process(pid).memory_info().rss / 1e6


def test_a_crowd_of_stream_clients_that_stop_reading_is_bounded_and_its_memory_given_back(net):
    web_pid = net.children()["web"]
    ok, run = net.query("vrsim/scenario/start?clock=lockstep", b"")  # the built-in default: a big layer
    assert ok, run
    time.sleep(PAINT_S)  # every hello carries the cells painted so far
    base = rss_mb(web_pid)
    clients, peak, slowest_s = [], base, 0.0
    try:
        for _ in range(CROWD):
            clients.append(Client(net.web))
            peak = max(peak, rss_mb(web_pid))
        deadline = time.monotonic() + HOLD_S
        while time.monotonic() < deadline:
            peak = max(peak, rss_mb(web_pid))
            asked = time.monotonic()
            try:  # the service still answers
                status = net.web.get("/api/status", timeout_s=ANSWER_DEADLINE_S)[0]
            except TimeoutError:
                pytest.fail(f"/api/status did not answer within {ANSWER_DEADLINE_S:g} s with the crowd there")
            assert status == 200, status
            slowest_s = max(slowest_s, time.monotonic() - asked)
            time.sleep(0.2)
    finally:
        for c in clients:
            c.close()
    left = []
    for _ in range(LEFT_S * 5):  # the crowd has gone: what the process does next counts too
        time.sleep(0.2)
        left.append(rss_mb(web_pid))
    net.query("vrsim/scenario/stop")
    peak, after = max(peak, *left), left[-1]
    print(f"\nweb RSS: {base:.0f} MB before, peak {peak:.0f} MB with {CROWD} stream clients that stop "
          f"reading ({MAX_STREAMS} streams at most) over {HOLD_S:g} s, {after:.0f} MB {LEFT_S} s after they "
          f"left; /api/status answered within {slowest_s:.1f} s throughout")
    assert peak - base < GROWTH_BOUND_MB
    assert after - base < LEFT_BOUND_MB


# ------------------------------------------------------------------- beyond loopback: 127.0.0.2
def test_a_page_beyond_loopback_on_a_bus_without_tls_is_refused_before_anything_starts(tmp_path):
    done = subprocess.run([VRSIM, "serve", "all", "--web", "--web-listen", f"127.0.0.2:{free_port()}",
                           "--listen", f"tcp/127.0.0.1:{free_port()}"], cwd=tmp_path, capture_output=True,
                          timeout=60)
    assert done.returncode == 2
    assert "beyond loopback the page needs TLS" in done.stderr.decode()


@pytest.fixture(scope="module")
def wide(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("webwide"))
    port = free_port()
    server = ServeAll(folder, "--tls", "--web", "--web-listen", f"127.0.0.2:{port}", scheme="tls")
    try:
        server.wait_ready()
        deadline = time.monotonic() + 30
        while (token := printed_token(server.output(), port)) is None:
            assert time.monotonic() < deadline, server.output()
            time.sleep(0.2)
        server.web_port, server.token = port, token
        yield server
    finally:
        rc = server.stop()
        assert rc == 0, server.output()


def https(server, method: str, path: str, headers: dict | None = None, body: bytes | None = None):
    """(status, headers) over TLS, the certificate checked against the bus's CA."""
    context = ssl.create_default_context(cafile=os.path.join(server.state, "tls", "ca.pem"))
    context.check_hostname = False  # the bus's certificate names 127.0.0.1, localhost and ::1
    conn = http.client.HTTPSConnection("127.0.0.2", server.web_port, timeout=30, context=context)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        resp = conn.getresponse()
        resp.read()
        return resp.status, resp
    finally:
        conn.close()


def test_beyond_loopback_the_page_is_tls_with_the_buses_ca(wide):
    assert f"page at https://127.0.0.2:{wide.web_port}/?token=" in wide.output()
    status, _ = https(wide, "GET", "/login")
    assert status == 200
    conn = http.client.HTTPConnection("127.0.0.2", wide.web_port, timeout=10)
    with pytest.raises((ConnectionError, http.client.HTTPException)):
        conn.request("GET", "/login")  # plain HTTP gets no page
        conn.getresponse()
    conn.close()


def test_beyond_loopback_a_forged_host_is_refused_even_logged_in(wide):
    status, resp = https(wide, "GET", f"/?token={wide.token}")
    assert status == 303
    cookie = resp.getheader("set-cookie")
    assert "Secure" in cookie and "HttpOnly" in cookie
    cookie, key = cookie.split(";")[0], resp.getheader("x-vrsim-key")
    host = f"127.0.0.2:{wide.web_port}"
    status, _ = https(wide, "GET", "/api/status", {"Cookie": cookie, "X-Vrsim-Key": key, "Host": host})
    assert status == 200
    forged = f"evil.example:{wide.web_port}"  # DNS rebinding: evil.example resolved to 127.0.0.2
    status, _ = https(wide, "POST", "/api/stop", {"Cookie": cookie, "Host": forged,
                                                  "Origin": f"https://{forged}"})
    assert status == 400
    status, _ = https(wide, "GET", "/api/status", {"Cookie": cookie, "Host": forged})
    assert status == 400
