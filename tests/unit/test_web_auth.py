"""Who may ask the web page (services/bus/web/auth.py, app.py), driven through ASGI in this process:
logins and sessions, roles and CSRF on start and stop, the headers every answer carries, the Host
allow-list, the cap on event streams and a browser that stops reading being dropped. The same cases
over real sockets are in tests/integration/test_web_trust.py."""

from __future__ import annotations

import asyncio
import json

import pytest

from tests.unit.test_web_app import until
from vrsim.services.bus.web import _allowed_hosts
from vrsim.services.bus.web import app as web_app
from vrsim.services.bus.web.app import create_app
from vrsim.services.bus.web.auth import Logins
from vrsim.services.bus.web.live import LiveView

PASSWORDS = {"operator": "op-secret", "viewer": "view-secret", "map": "map-secret"}


class NoBus:
    """The bridge's attributes the routes use; its queries answer at once."""

    viewers = 0
    map_png = None
    map_scale = None

    def status(self) -> dict:
        return {"state": "idle"}

    def map_info(self) -> dict:
        return {"crs": "EPSG:32632"}


class FakeOperator:
    """Records the requests that got through."""

    def __init__(self):
        self.done: list[str] = []

    def check(self, verb: str, params: dict) -> None:
        pass

    def request(self, verb: str, body: bytes | None = None, params: dict | None = None) -> dict:
        self.done.append(verb)
        return {"ok": verb}


def scope(method: str, path: str, headers: dict, query: str = "") -> dict:
    raw = [(k.lower().encode(), v.encode()) for k, v in {"host": "127.0.0.1:8448", **headers}.items()]
    return {"type": "http", "asgi": {"version": "3.0", "spec_version": "2.4"}, "http_version": "1.1",
            "method": method, "scheme": "http", "path": path, "raw_path": path.encode(),
            "query_string": query.encode(), "root_path": "", "headers": raw, "server": ("127.0.0.1", 8448),
            "client": ("127.0.0.1", 50000)}


def call(app, method: str, path: str, headers: dict | None = None, body: bytes = b"",
         query: str = "") -> tuple[int, dict, bytes]:
    """(status, headers, body) of one request that ends."""
    out: list = []

    async def receive():
        return {"type": "http.request", "body": body, "more_body": False}

    async def send(message):
        out.append(message)

    asyncio.run(app(scope(method, path, headers or {}, query), receive, send))
    start = out[0]
    return (start["status"], {k.decode(): v.decode() for k, v in start["headers"]},
            b"".join(m.get("body", b"") for m in out[1:]))


def service(operator=True, **kwargs):
    logins = Logins("operator" if operator else "viewer", PASSWORDS, "vrsim_session_8448")
    op = FakeOperator() if operator else None
    return create_app(LiveView(), NoBus(), op, logins, **kwargs), logins, op


def session(app, logins: Logins, role: str) -> tuple[dict, str]:
    """Headers of a logged-in browser of ``role`` (its cookie and the page's key) and its CSRF token (as
    the page gets it)."""
    sid = logins.open(role)
    headers = {"cookie": f"{logins.cookie}={sid}", "x-vrsim-key": logins.sessions[sid].key}
    status, _, body = call(app, "GET", "/api/view", headers)
    assert status == 200
    return headers, json.loads(body)["csrf"]


@pytest.mark.parametrize("path", ["/events", "/api/map", "/api/status", "/api/view", "/api/map.png",
                                  "/api/report", "/static/view.js"])
def test_every_route_without_a_session_is_401(path):
    app, _, _ = service()
    status, _, body = call(app, "GET", path)
    assert status == 401 and b"log in first" in body


def test_the_page_without_a_session_goes_to_the_login_page_which_needs_none():
    app, _, _ = service()
    status, headers, _ = call(app, "GET", "/")
    assert status == 303 and headers["location"] == "/login"
    status, _, body = call(app, "GET", "/login")
    assert status == 200 and b'<form method="post" action="/login">' in body


def test_the_token_in_the_url_opens_a_session_and_the_redirect_drops_it():
    app, logins, _ = service()
    status, headers, _ = call(app, "GET", "/", query=f"token={logins.token}&x=1")
    assert status == 303 and headers["location"] == f"/?x=1#key={headers['x-vrsim-key']}"
    cookie = headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and cookie.startswith("vrsim_session_8448=")
    sid = cookie.split(";")[0].split("=", 1)[1]
    both = {"cookie": f"vrsim_session_8448={sid}", "x-vrsim-key": headers["x-vrsim-key"]}
    assert call(app, "GET", "/api/status", both)[0] == 200
    status, _, body = call(app, "GET", "/", query="token=not-it")
    assert status == 303  # to the login page
    assert call(app, "GET", "/api/status", query="token=not-it")[0] == 401


def test_passwords_of_the_people_users_log_in_and_nothing_else_does():
    app, logins, _ = service()
    form = "application/x-www-form-urlencoded"
    for fields, code in (("user=viewer&password=view-secret", 303), ("user=operator&password=op-secret", 303),
                         ("user=viewer&password=op-secret", 401), ("user=map&password=map-secret", 401),
                         (f"token={logins.token}", 303), ("token=nope", 401), ("", 401)):
        status, headers, _ = call(app, "POST", "/login", {"content-type": form}, fields.encode())
        assert status == code, fields
    status, _, body = call(app, "POST", "/login", {"origin": "http://evil.example"},
                           b"user=viewer&password=view-secret")
    assert status == 403 and b"another site" in body
    roles = sorted(s.role for s in logins.sessions.values())
    assert roles == ["operator", "operator", "viewer"]


def test_start_and_stop_need_a_session_the_operator_role_and_the_csrf_token():
    app, logins, op = service()
    assert call(app, "POST", "/api/start")[0] == 401
    viewer, viewer_csrf = session(app, logins, "viewer")
    status, _, body = call(app, "POST", "/api/stop", {**viewer, "x-csrf-token": viewer_csrf})
    assert status == 403 and b"viewer" in body
    operator, csrf = session(app, logins, "operator")
    wrong = (operator, {**operator, "x-csrf-token": "guess"}, {**operator, "x-csrf-token": viewer_csrf})
    for headers in wrong:
        status, _, body = call(app, "POST", "/api/start", headers)
        assert status == 403 and b"X-CSRF-Token" in body
    assert op.done == []
    assert call(app, "POST", "/api/stop", {**operator, "x-csrf-token": csrf})[0] == 200
    assert call(app, "POST", "/api/start", {**operator, "x-csrf-token": csrf}, b"")[0] == 200
    assert op.done == ["stop", "start"]


def test_an_operators_password_on_a_viewer_service_is_a_viewer():
    app, logins, _ = service(operator=False)
    form = {"content-type": "application/x-www-form-urlencoded"}
    status, headers, _ = call(app, "POST", "/login", form, b"user=operator&password=op-secret")
    sid = headers["set-cookie"].split(";")[0].split("=", 1)[1]
    status, _, body = call(app, "GET", "/api/view", {"cookie": f"vrsim_session_8448={sid}",
                                                     "x-vrsim-key": headers["x-vrsim-key"]})
    assert json.loads(body)["role"] == "viewer"


def test_every_answer_forbids_framing():
    app, logins, _ = service(allowed_hosts=_allowed_hosts("0.0.0.0"))
    viewer, _ = session(app, logins, "viewer")
    answers = [call(app, "GET", "/"), call(app, "GET", "/login"), call(app, "GET", "/api/status"),
               call(app, "GET", "/api/status", viewer), call(app, "GET", "/", viewer),
               call(app, "GET", "/", {"host": "evil.example"})]
    for status, headers, _ in answers:
        assert headers["x-frame-options"] == "DENY", status
        assert "frame-ancestors 'none'" in headers["content-security-policy"]


@pytest.mark.parametrize("listen, host", [("0.0.0.0", "127.0.0.1"), ("127.0.0.2", "127.0.0.2"),
                                          ("127.0.0.1", "localhost"), ("::1", "[::1]")])
def test_a_forged_host_is_refused_on_every_listen_address(listen, host):
    app, logins, _ = service(allowed_hosts=_allowed_hosts(listen))
    operator, csrf = session(app, logins, "operator")
    forged = {**operator, "x-csrf-token": csrf, "host": "evil.example:8448", "origin": "http://evil.example:8448"}
    status, _, _ = call(app, "POST", "/api/start", forged)
    assert status == 400
    assert call(app, "GET", "/api/status", {**operator, "host": f"{host}:8448"})[0] == 200


async def _streams(app, logins: Logins, n: int, reading: bool):
    """Open ``n`` /events streams; returns (their first messages, the tasks, a way to end them)."""
    life_in: asyncio.Queue = asyncio.Queue()
    life_out: list = []
    await life_in.put({"type": "lifespan.startup"})

    async def life_send(message):
        life_out.append(message["type"])

    lifespan = asyncio.create_task(app({"type": "lifespan", "asgi": {"version": "3.0"}}, life_in.get,
                                       life_send))
    while "lifespan.startup.complete" not in life_out:
        await asyncio.sleep(0.01)
    sid = logins.open("viewer")
    cookie = {"cookie": f"{logins.cookie}={sid}", "x-vrsim-key": logins.sessions[sid].key}
    leave = asyncio.Event()
    starts: list = []
    sent: list = []

    async def receive():
        await leave.wait()
        return {"type": "http.disconnect"}

    async def send(message):
        if message["type"] == "http.response.start":
            starts.append(message["status"])
        elif message.get("body"):
            sent.append(message["body"])
            if not reading:
                await asyncio.sleep(3600)  # the browser takes nothing more

    tasks = [asyncio.create_task(app(scope("GET", "/events", cookie), receive, send)) for _ in range(n)]

    async def end():
        leave.set()
        await asyncio.wait_for(asyncio.gather(*tasks), 5)
        await life_in.put({"type": "lifespan.shutdown"})
        await asyncio.wait_for(lifespan, 5)

    return starts, sent, end


def test_streams_beyond_the_cap_are_503():
    app, logins, _ = service(max_streams=3)

    async def run():
        starts, _, end = await _streams(app, logins, 5, reading=True)
        await until(lambda: len(starts) == 5, "not every stream was answered")
        opened = app.state.streams.open
        await end()
        return sorted(starts), opened, app.state.streams.open

    starts, opened, after = asyncio.run(run())
    assert starts == [200, 200, 200, 503, 503]
    assert opened == 3 and after == 0


def test_a_browser_that_takes_nothing_is_dropped_and_its_stream_freed(monkeypatch):
    monkeypatch.setattr(web_app, "SEND_TIMEOUT_S", 0.3)
    app, logins, _ = service(max_streams=2)

    async def run():
        starts, sent, end = await _streams(app, logins, 2, reading=False)
        await until(lambda: app.state.streams.dropped == 2, "the streams that take nothing were not dropped")
        dropped, pieces = app.state.streams.dropped, len(sent)
        await end()
        return starts, dropped, pieces, app.state.streams.open

    starts, dropped, pieces, after = asyncio.run(run())
    assert starts == [200, 200]
    assert dropped == 2 and pieces == 2  # one piece each, then nothing more was made for them
    assert after == 0
