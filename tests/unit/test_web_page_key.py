"""The session's second half (issue #41): a browser sends its cookie to every port of a host, so a
server of another local user can be lured into receiving it; the page's key (handed to the page in
the login redirect's fragment, sent back in ``X-Vrsim-Key``) it never sends there. Driven through
ASGI in this process (services/bus/web/auth.py, app.py); with a real browser and another port's
server: tests/integration/test_web_doors.py. Also: the login's redirect stays on this server, and an
answer made by an exception carries the security headers too."""

from __future__ import annotations

import asyncio
import json

import pytest

from tests.unit.test_web_auth import PASSWORDS, NoBus, call, scope, service
from vrsim.services.bus.web.app import create_app
from vrsim.services.bus.web.auth import Logins
from vrsim.services.bus.web.live import LiveView

KEY_ROUTES = [("GET", "/api/view"), ("GET", "/api/status"), ("GET", "/api/map"), ("GET", "/api/map.png"),
              ("GET", "/api/report"), ("GET", "/events"), ("POST", "/api/stop"), ("POST", "/api/start")]


def halves(logins: Logins, role: str = "operator") -> tuple[dict, str]:
    """(the cookie's header, the page's key) of a new session."""
    sid = logins.open(role)
    return {"cookie": f"{logins.cookie}={sid}"}, logins.sessions[sid].key


@pytest.mark.parametrize("method, path", KEY_ROUTES)
def test_a_cookie_alone_is_no_login(method, path):
    app, logins, op = service()
    cookie, key = halves(logins)
    csrf = json.loads(call(app, "GET", "/api/view", {**cookie, "x-vrsim-key": key})[2])["csrf"]
    # What a lured browser hands another port's server, replayed with everything but the key.
    status, headers, body = call(app, method, path, {**cookie, "x-csrf-token": csrf})
    assert status == 401 and b"X-Vrsim-Key" in body
    assert headers["x-frame-options"] == "DENY"
    assert call(app, method, path, {**cookie, "x-csrf-token": csrf, "x-vrsim-key": "guess"})[0] == 401
    assert op.done == []


def test_the_cookie_with_its_own_key_works_and_with_another_sessions_key_does_not():
    app, logins, op = service()
    cookie, key = halves(logins)
    _, other_key = halves(logins)
    status, _, body = call(app, "GET", "/api/view", {**cookie, "x-vrsim-key": key})
    assert status == 200
    csrf = json.loads(body)["csrf"]
    for given, status in ((other_key, 401), (key, 200)):
        headers = {**cookie, "x-vrsim-key": given, "x-csrf-token": csrf}
        assert call(app, "POST", "/api/stop", headers)[0] == status
    assert op.done == ["stop"]


def test_the_page_and_its_static_files_need_the_cookie_only():
    """A navigation and a <script src> cannot send a header; what they get is the same for everyone."""
    app, logins, _ = service()
    cookie, _ = halves(logins)
    status, _, body = call(app, "GET", "/", cookie)
    assert status == 200 and b'src="/static/view.js"' in body
    assert call(app, "GET", "/static/view.js", cookie)[0] == 200
    assert call(app, "GET", "/static/view.js")[0] == 401
    assert call(app, "GET", "/")[0] == 303


def test_a_login_hands_the_key_in_the_fragment_and_a_header_never_in_the_cookie():
    app, logins, _ = service()
    form = {"content-type": "application/x-www-form-urlencoded"}
    for fields in (b"user=operator&password=op-secret", f"token={logins.token}".encode()):
        status, headers, _ = call(app, "POST", "/login", form, fields)
        sid = headers["set-cookie"].split(";")[0].split("=", 1)[1]
        key = logins.sessions[sid].key
        assert status == 303 and headers["location"] == f"/#key={key}" and headers["x-vrsim-key"] == key
        assert key not in headers["set-cookie"] and key != sid
    status, headers, _ = call(app, "GET", "/", query=f"token={logins.token}")
    assert status == 303 and headers["location"] == f"/#key={headers['x-vrsim-key']}"


@pytest.mark.parametrize("path, raw, to", [
    ("//evil.example/", b"//evil.example/", "/"),
    ("/\\evil.example/", b"/\\evil.example/", "/"),
    ("///evil.example", b"///evil.example", "/"),
    ("//evil.example/", b"/%2F/evil.example/", "/%2F/evil.example/"),  # percent-encoded: a local path
    ("/api/status", b"/api/status", "/api/status"),
    ("/", b"/", "/"),
])
def test_the_token_redirect_stays_on_this_server(path, raw, to):
    app, logins, _ = service()
    out: list = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message):
        out.append(message)

    request = {**scope("GET", path, {}, f"token={logins.token}"), "raw_path": raw}
    asyncio.run(app(request, receive, send))
    assert out[0]["status"] == 303
    location = dict(out[0]["headers"])[b"location"].decode()
    assert location.split("#", 1)[0] == to


class BrokenBus(NoBus):
    def status(self) -> dict:
        raise RuntimeError("a bug")


def test_an_exception_in_the_app_is_a_500_with_the_security_headers():
    logins = Logins("viewer", PASSWORDS, "vrsim_session_8448")
    app = create_app(LiveView(), BrokenBus(), None, logins)
    cookie, key = halves(logins, "viewer")
    out: list = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message):
        out.append(message)

    with pytest.raises(RuntimeError, match="a bug"):  # re-raised for uvicorn to log
        asyncio.run(app(scope("GET", "/api/status", {**cookie, "x-vrsim-key": key}), receive, send))
    start = out[0]
    assert start["status"] == 500
    assert dict(start["headers"])[b"x-frame-options"] == b"DENY"
