"""Who is asking the web page: logins, sessions, CSRF and the headers every response carries.

A login is the token made at start (printed with the page's URL, ``/?token=...``, as Jupyter does)
or the password of the bus's ``operator`` or ``viewer`` user from the state folder (``/login``). It
is exchanged for a session in two halves: a random id in an HttpOnly, SameSite=Strict cookie (Secure
over TLS), and a key the login's redirect hands to the page in the URL's fragment (and to a script in
``X-Vrsim-Key``), which the page keeps in its origin's storage and sends back in ``X-Vrsim-Key``. A
browser sends the cookie to every port of the host, so a server of another local user on another
port can be lured into receiving it; the key it never sends there. The session also holds its role
and a CSRF token that the page's script sends back in ``X-CSRF-Token`` with every POST.

Without the cookie every route answers 401 (the page: a redirect to ``/login``), but the login page
and its stylesheet; without the key too, but the page itself and its static files (`_needs_key`),
which hold nothing of the session. See docs/security.md, "The web page".
"""

from __future__ import annotations

import hmac
import re
import secrets
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlencode

from starlette.requests import cookie_parser
from starlette.responses import JSONResponse, PlainTextResponse, RedirectResponse

TOKEN_BYTES = 32  # secrets.token_urlsafe: 43 characters
SESSION_TTL_S = 12 * 3600.0
MAX_SESSIONS = 256  # the oldest is forgotten beyond this (a login loop cannot grow memory)
CSRF_HEADER = "x-csrf-token"
KEY_HEADER = "x-vrsim-key"
PUBLIC_PATHS = frozenset({"/login", "/favicon.ico", "/static/view.css"})
# A redirect stays on this server: a path with one leading "/" ("//host" and, in browsers, "/\host" are
# another host), printable ASCII (uvicorn's raw path, still percent-encoded).
LOCAL_PATH = re.compile(r"/(?![/\\])[!-~]*")
LOGIN_USERS = ("operator", "viewer")  # the bus's people users; a service's password is no login here
# default-src 'self': the page's script, style, images and /events, from this server only.
SECURITY_HEADERS = [
    (b"x-frame-options", b"DENY"),
    (b"content-security-policy",
     b"default-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'; object-src 'none'"),
    (b"x-content-type-options", b"nosniff"),
    # The token in a URL never leaves in a Referer to another site (no-referrer would also make a
    # form's Origin "null", which the login refuses as another site's).
    (b"referrer-policy", b"same-origin"),
]


@dataclass
class Session:
    """One logged-in browser: its ``role`` (``operator`` or ``viewer``), CSRF token and the page's key."""

    role: str
    csrf: str
    key: str
    expires_s: float  # time.monotonic() after which it is gone


class Logins:
    """The login token, the passwords that may log in, and the open sessions.

    Parameters
    ----------
    role : str
        What the token gives: ``operator`` when this web service may start and stop runs, else
        ``viewer``; the operator's password gives no more than this either.
    passwords : mapping, optional
        User -> password from the state folder (None: an ``--insecure`` bus, the token only).
    cookie : str
        The cookie's name (one per port: browsers share cookies between the ports of a host).
    secure : bool
        The page is served over TLS: the cookie is marked Secure.
    """

    def __init__(self, role: str, passwords: Mapping[str, str] | None, cookie: str, secure: bool = False):
        self.token = secrets.token_urlsafe(TOKEN_BYTES)
        self.role = role
        self.passwords = {u: p for u, p in (passwords or {}).items() if u in LOGIN_USERS}
        self.cookie = cookie
        self.secure = secure
        self.sessions: OrderedDict[str, Session] = OrderedDict()

    def by_token(self, token: str) -> str | None:
        """The role ``token`` logs in as (None: not the token)."""
        return self.role if _same(token, self.token) else None

    def by_password(self, user: str, password: str) -> str | None:
        """The role ``user`` with ``password`` logs in as (None: no such login)."""
        known = self.passwords.get(user)
        if known is None or not _same(password, known):
            return None
        return "operator" if user == "operator" and self.role == "operator" else "viewer"

    def open(self, role: str) -> str:
        """A new session of ``role``; returns its id (the cookie's value)."""
        now = time.monotonic()
        for sid in [s for s, v in self.sessions.items() if v.expires_s < now]:
            del self.sessions[sid]
        while len(self.sessions) >= MAX_SESSIONS:
            self.sessions.popitem(last=False)
        sid = secrets.token_urlsafe(TOKEN_BYTES)
        csrf, key = secrets.token_urlsafe(TOKEN_BYTES), secrets.token_urlsafe(TOKEN_BYTES)
        self.sessions[sid] = Session(role, csrf, key, now + SESSION_TTL_S)
        return sid

    def find(self, headers: Mapping[str, str]) -> Session | None:
        """The session the request's cookie names, if it is open."""
        sid = cookie_parser(headers.get("cookie", "")).get(self.cookie)
        session = self.sessions.get(sid) if sid else None
        if session is None or session.expires_s < time.monotonic():
            return None
        return session

    def logged_in(self, sid: str, to: str) -> RedirectResponse:
        """303 to ``to`` setting the session cookie, with the session's key in the fragment (for the page:
        no server sees a fragment) and in ``X-Vrsim-Key`` (for a script)."""
        key = self.sessions[sid].key
        response = RedirectResponse(f"{to}#key={key}", status_code=303,
                                    headers={"Cache-Control": "no-store", KEY_HEADER: key})
        response.set_cookie(self.cookie, sid, max_age=int(SESSION_TTL_S), path="/", httponly=True,
                            samesite="strict", secure=self.secure)
        return response


def _key_ok(session: Session, headers: Mapping[str, str]) -> bool:
    """The request carries the session's key in ``X-Vrsim-Key`` (the cookie alone is half a session)."""
    return _same(headers.get(KEY_HEADER, ""), session.key)


def _needs_key(path: str) -> bool:
    """Whether ``path`` needs the key as well as the cookie: all but the page and its static files
    (a navigation or a ``<script src>`` cannot send a header; they are the same for everyone)."""
    return path != "/" and not path.startswith("/static/")


def _local_path(scope) -> str:
    """The request's path as a redirect target on this server (``/`` for anything else)."""
    raw = scope.get("raw_path") or scope["path"].encode("utf-8", "replace")
    path = raw.decode("latin-1")
    return path if LOCAL_PATH.fullmatch(path) else "/"


def csrf_ok(session: Session, headers: Mapping[str, str]) -> bool:
    """The request carries the session's CSRF token in ``X-CSRF-Token``."""
    return _same(headers.get(CSRF_HEADER, ""), session.csrf)


def _same(given: str, expected: str) -> bool:
    return hmac.compare_digest(given.encode("utf-8", "replace"), expected.encode())


class LoginGate:
    """ASGI middleware: ``?token=`` in any URL opens a session and redirects to the URL without it (a
    path on this server only); a request without a session gets 401 (``/``: a redirect to
    ``/login``), but `PUBLIC_PATHS`, and so does one without the session's key where `_needs_key`. The
    session is ``request.state.session``."""

    def __init__(self, app, logins: Logins):
        self.app = app
        self.logins = logins

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
        query = parse_qsl(scope.get("query_string", b"").decode("latin-1"), keep_blank_values=True)
        token = [v for k, v in query if k == "token"]
        if token:
            role = self.logins.by_token(token[-1])
            if role is None:
                return await _unauthorized(scope["path"], "the token is not this server's (see the URL "
                                                          "printed at start)")(scope, receive, send)
            rest = urlencode([(k, v) for k, v in query if k != "token"])
            to = _local_path(scope) + (f"?{rest}" if rest else "")
            response = self.logins.logged_in(self.logins.open(role), to)
            return await response(scope, receive, send)
        session = self.logins.find(headers)
        path = scope["path"]
        if session is None and path not in PUBLIC_PATHS:
            return await _unauthorized(path, "log in first: open the URL printed at start "
                                             "(it carries a token) or /login")(scope, receive, send)
        half = session is not None and path not in PUBLIC_PATHS and _needs_key(path)
        if half and not _key_ok(session, headers):
            return await _unauthorized(path, "the session's key is missing or wrong (X-Vrsim-Key: the page "
                                             "sends it; a cookie alone is no login): log in again at "
                                             "/login")(scope, receive, send)
        scope.setdefault("state", {})["session"] = session
        await self.app(scope, receive, send)


def _unauthorized(path: str, message: str):
    if path == "/":
        return RedirectResponse("/login", status_code=303, headers={"Cache-Control": "no-store"})
    return JSONResponse({"error": message}, status_code=401, headers={"WWW-Authenticate": "Cookie"})


class SecurityHeaders:
    """ASGI middleware, outermost (outside Starlette's own error handler, so its 500 too):
    `SECURITY_HEADERS` on every response (no other site may frame the page). An exception before any
    answer is answered 500 here, so uvicorn's own 500 (which carries none) is never sent."""

    def __init__(self, app):
        self.app = app
        self.state = getattr(app, "state", None)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False

        async def with_headers(message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                message = {**message, "headers": [*message.get("headers", []), *SECURITY_HEADERS]}
            await send(message)

        try:
            await self.app(scope, receive, with_headers)
        except Exception:
            if not started:
                failed = PlainTextResponse("Internal Server Error", status_code=500)
                await failed(scope, receive, with_headers)
            raise
