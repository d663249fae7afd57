"""The web side: the page, ``/events`` (Server-Sent Events, thinned) and the JSON API (docs/api.md).

Frames: one task closes a frame of the `LiveView` at most every `FRAME_S` when anything changed and
wakes the streams; each stream sends one event per frame at most (``hello`` to start over, else
``frame``: what changed since the frame it sent last). A browser slower than that skips frames: its
next event covers all it missed. Memory per browser is bounded: at most `MAX_STREAMS` streams (503
beyond), a stream keeps only the seq and epoch it sent last, sends an event in pieces of
`PIECE_BYTES` and is dropped when its browser has not taken a piece within `SEND_TIMEOUT_S` (uvicorn
stops at 64 KB of unsent bytes), and streams starting on the same frame share one encoded ``hello``.

Who may ask (`auth`): every route but the login page needs a session (its cookie, and its key but
for the page and its static files); start and stop an operator's session and its CSRF token; the
Host header must be one of ``allowed_hosts``. How many may connect, and for how long: `guard`.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import os
import time
from urllib.parse import parse_qsl

import orjson
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from vrsim.common import VrsimError
from vrsim.services.bus.web import upload
from vrsim.services.bus.web.auth import LoginGate, Logins, SecurityHeaders, csrf_ok
from vrsim.services.bus.web.bridge import RUN_ID, Bridge, Operator
from vrsim.services.bus.web.live import FRAME_S, LiveView

STATIC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "web_static")
KEEPALIVE_S = 15.0  # a comment line this often: proxies keep the stream open, a gone browser is noticed
MAX_SCENARIO_BYTES = 1_000_000
MAX_LOGIN_BYTES = 4096
LOOPBACK_HOSTS = ["127.0.0.1", "localhost"]
MAX_STREAMS = 64  # open /events at once (each browser tab holds one)
SEND_TIMEOUT_S = 5.0  # a browser that takes no piece of an event for this long is dropped
PIECE_BYTES = 16384  # an event leaves in pieces: a stalled browser holds at most one beyond uvicorn's 64 KB
GIVE_BACK_S = 2.0  # after streams ended, free heap pages go back to the system this often at most
STREAM_HEADERS = [(b"content-type", b"text/event-stream; charset=utf-8"), (b"cache-control", b"no-store"),
                  (b"x-accel-buffering", b"no")]


class _Frames:
    """Closes frames at most every `FRAME_S` and wakes the streams waiting for one."""

    def __init__(self, view: LiveView):
        self.view = view
        self.event = asyncio.Event()
        self.closing = False
        self.hello: tuple | None = None  # (epoch, seq, encoded at (monotonic s), the event's bytes)

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        while not self.closing:
            started = loop.time()
            if self.view.frame() is not None:
                self.event.set()
                self.event = asyncio.Event()
            await asyncio.sleep(max(0.0, started + FRAME_S - loop.time()))

    async def next(self, seq: int) -> bool:
        """Until a frame after ``seq`` exists (True) or `KEEPALIVE_S` passed (False)."""
        if self.view.seq > seq:
            return True
        try:
            await asyncio.wait_for(self.event.wait(), KEEPALIVE_S)
        except TimeoutError:
            return False
        return True

    def encoded_hello(self) -> tuple[int, int, bytes]:
        """(epoch, seq, event) of a ``hello``: the one encoded for this frame in the last `FRAME_S`
        (so its ``sent_unix`` is that close) when there is one, shared by every stream that asks."""
        now = time.monotonic()
        cached = self.hello
        if cached is None or cached[:2] != (self.view.epoch, self.view.seq) or now - cached[2] > FRAME_S:
            doc = self.view.hello()
            cached = self.hello = (doc["epoch"], doc["seq"], now, _sse("hello", doc))
        return cached[0], cached[1], cached[3]


class _Streams:
    """The open ``/events`` streams: at most ``limit``; how many ended, and were dropped for not
    reading."""

    def __init__(self, limit: int):
        self.limit = limit
        self.open = 0
        self.ended = 0
        self.dropped = 0

    async def give_back(self) -> None:
        """After streams ended, hand the heap's free pages back to the system: the events and buffers
        of a crowd of browsers are freed when they go, but glibc keeps the pages (``malloc_trim``)."""
        trim = _malloc_trim()
        seen = self.ended
        while trim is not None:
            await asyncio.sleep(GIVE_BACK_S)
            if self.ended != seen:
                seen = self.ended
                trim(0)


def _malloc_trim():
    """glibc's ``malloc_trim`` (None on another C library)."""
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        return None


def _sse(kind: str, doc: dict) -> bytes:
    """One event; ``sent_unix``: when it left (wall clock, s), for a client's own latency figures."""
    doc["sent_unix"] = time.time()
    return b"event: " + kind.encode() + b"\ndata: " + orjson.dumps(doc) + b"\n\n"


class _EventStream:
    """The ASGI response of one ``/events``: events of `_Frames` until the browser goes (then at once,
    not at the next event) or is dropped for not reading."""

    def __init__(self, frames: _Frames, streams: _Streams, bridge: Bridge):
        self.frames, self.streams, self.bridge = frames, streams, bridge

    async def __call__(self, scope, receive, send) -> None:
        self.bridge.viewers += 1
        try:
            await send({"type": "http.response.start", "status": 200, "headers": STREAM_HEADERS})
            producer = asyncio.create_task(self._produce(send))
            gone = asyncio.create_task(_disconnected(receive))
            try:
                await asyncio.wait({producer, gone}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                producer.cancel()
            if not gone.done() and producer.result():  # shutting down: end the body
                gone.cancel()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(send({"type": "http.response.body", "body": b""}), SEND_TIMEOUT_S)
            else:  # dropped (nothing more is sent or kept for it: its slot is held, so such connections
                await gone  # stay at most `MAX_STREAMS`), or gone; the connection ends with the browser
        finally:
            self.streams.open -= 1
            self.streams.ended += 1
            self.bridge.viewers -= 1

    async def _produce(self, send) -> bool:
        """Send events until the service closes (True) or the browser stops taking them (False)."""
        loop, frames = asyncio.get_running_loop(), self.frames
        epoch, seq, event = frames.encoded_hello()
        sent = loop.time()
        while await self._send(send, event):
            event = None
            while event is None:
                if frames.closing:
                    return True
                if not await frames.next(seq):
                    event = b": keepalive\n\n"
                    continue
                # Events of one stream leave at least FRAME_S apart, also after a stall.
                await asyncio.sleep(max(0.0, sent + FRAME_S - loop.time()))
                if frames.closing:
                    return True
                if frames.view.epoch != epoch:
                    epoch, seq, event = frames.encoded_hello()
                else:
                    doc = frames.view.delta(seq, epoch)
                    epoch, seq, event = doc["epoch"], doc["seq"], _sse(doc["type"], doc)
                sent = loop.time()
        self.streams.dropped += 1
        return False

    @staticmethod
    async def _send(send, event: bytes) -> bool:
        view = memoryview(event)
        for a in range(0, len(event), PIECE_BYTES):
            piece = bytes(view[a:a + PIECE_BYTES])
            message = {"type": "http.response.body", "body": piece, "more_body": True}
            try:
                await asyncio.wait_for(send(message), SEND_TIMEOUT_S)
            except TimeoutError:
                return False
        return True


async def _disconnected(receive) -> None:
    while (await receive())["type"] != "http.disconnect":
        pass


def create_app(view: LiveView, bridge: Bridge, operator: Operator | None, logins: Logins,
               allowed_hosts: list[str] | None = None, max_streams: int = MAX_STREAMS) -> SecurityHeaders:
    """The Starlette app, inside `SecurityHeaders` (its ``state`` is the app's). ``operator`` None: a
    viewer (start and stop answer 403); ``logins``: who may ask; ``allowed_hosts``: Host headers
    accepted (against DNS rebinding; None: any); ``max_streams``: open ``/events`` streams at most."""
    frames = _Frames(view)
    streams = _Streams(max_streams)

    @contextlib.asynccontextmanager
    async def lifespan(app):
        frames.event = asyncio.Event()  # bound to uvicorn's loop
        tasks = [asyncio.create_task(frames.run()), asyncio.create_task(streams.give_back())]
        try:
            yield
        finally:
            frames.closing = True
            frames.event.set()
            for task in tasks:
                task.cancel()

    async def page(request: Request) -> Response:
        return FileResponse(os.path.join(STATIC, "index.html"), headers={"Cache-Control": "no-cache"})

    async def login_page(request: Request) -> Response:
        return _login_form("", 200)

    async def login(request: Request) -> Response:
        refused = _other_site(request, "login")
        if refused is not None:
            return refused
        body = await _body(request, MAX_LOGIN_BYTES)
        form = dict(parse_qsl((body or b"").decode("utf-8", "replace"), keep_blank_values=True))
        token, user, password = (form.get(k, "") for k in ("token", "user", "password"))
        role = logins.by_token(token) if token else logins.by_password(user, password)
        if role is None:
            return _login_form("That did not log you in: wrong token, or wrong user or password.", 401)
        return logins.logged_in(logins.open(role), "/")

    async def events(request: Request) -> Response:
        if streams.open >= streams.limit:
            return _error(503, f"/events: {streams.limit} streams are open, the most this service keeps; "
                               "close a page and try again", {"Retry-After": "5"})
        streams.open += 1
        return _EventStream(frames, streams, bridge)

    async def view_doc(request: Request) -> Response:
        current = view.map
        session = request.state.session
        doc = {"role": _role(session, operator), "csrf": session.csrf, "frame_s": FRAME_S, "run": view.run,
               "map": None if current is None else {
                   "version": current["version"], "info": current["info"], "grid": current["grid"].to_dict(),
                   "scale": bridge.map_scale, "png": f"/api/map.png?v={current['version']}"}}
        return JSONResponse(doc, headers={"Cache-Control": "no-store"})

    async def map_png(request: Request) -> Response:
        if bridge.map_png is None:
            return _error(503, "no map yet: the map service has not answered")
        return Response(bridge.map_png, media_type="image/png", headers={"Cache-Control": "no-cache"})

    async def api_map(request: Request) -> Response:
        return await _bus(bridge.map_info)

    async def api_status(request: Request) -> Response:
        return await _bus(bridge.status)

    async def api_report(request: Request) -> Response:
        unknown = set(request.query_params) - {"run_id"}
        if unknown:
            return _error(400, f"/api/report: unknown parameter {sorted(unknown)[0]!r} (known: run_id)")
        run_id = request.query_params.get("run_id")
        if run_id is not None and not RUN_ID.match(run_id):
            return _error(400, f"/api/report: run_id={run_id[:80]!r} is not a run id")
        return await _bus(bridge.report, run_id)

    async def api_start(request: Request) -> Response:
        refused = _refuse_operator(request, operator, "start")
        if refused is not None:
            return refused
        params = dict(request.query_params)
        try:
            operator.check("start", params)
        except VrsimError as exc:
            return _error(400, str(exc))
        if request.headers.get("content-type", "").startswith("multipart/form-data"):
            return await _start_uploaded(request, operator, params, bridge.data_root())
        body = await _body(request, MAX_SCENARIO_BYTES)
        if body is None:
            return _error(413, f"/api/start: the scenario is larger than {MAX_SCENARIO_BYTES} bytes")
        return await _bus(operator.request, "start", body, params)

    async def api_stop(request: Request) -> Response:
        refused = _refuse_operator(request, operator, "stop")
        if refused is not None:
            return refused
        if request.query_params:
            return _error(400, "/api/stop: takes no parameters")
        return await _bus(operator.request, "stop")

    routes = [
        Route("/", page),
        Route("/login", login_page),
        Route("/login", login, methods=["POST"]),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
        Route("/events", events),
        Route("/api/view", view_doc),
        Route("/api/map", api_map),
        Route("/api/map.png", map_png),
        Route("/api/status", api_status),
        Route("/api/report", api_report),
        Route("/api/start", api_start, methods=["POST"]),
        Route("/api/stop", api_stop, methods=["POST"]),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    middleware = [Middleware(TrustedHostMiddleware, allowed_hosts=allowed_hosts)] if allowed_hosts else []
    middleware.append(Middleware(LoginGate, logins=logins))
    app = Starlette(routes=routes, middleware=middleware, lifespan=lifespan)
    app.state.streams = streams
    # Outside Starlette (whose error handler is outermost within it): every answer, a refused Host's
    # and a 500 too, carries the frame and content headers.
    return SecurityHeaders(app)


class _TooLarge(Exception):
    """A request body past its cap (raised while it is read)."""


def _capped(request: Request, limit: int) -> Request:
    """``request`` whose body raises `_TooLarge` once more than ``limit`` bytes came (counted, not
    trusted from Content-Length)."""
    seen = 0

    async def receive():
        nonlocal seen
        message = await request.receive()
        seen += len(message.get("body", b""))
        if seen > limit:
            raise _TooLarge
        return message

    return Request(request.scope, receive)


async def _start_uploaded(request: Request, operator: Operator, params: dict,
                          data_root: str | None) -> Response:
    """``/api/start`` with a multipart body: the scenario and its files (`upload.save`) kept under the
    data root, then started from there."""
    from starlette.concurrency import run_in_threadpool
    from starlette.datastructures import UploadFile
    from starlette.formparsers import MultiPartException

    if data_root is None:
        return _error(400, "/api/start: this web service keeps no uploads (it has no data root); send the "
                           "scenario's TOML text alone")
    too_large = _error(413, f"/api/start: the upload is larger than {upload.MAX_UPLOAD_BYTES >> 20} MB")
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > upload.MAX_UPLOAD_BYTES:
        return too_large  # said before it is sent; a body that says less is counted as it comes
    try:
        async with _capped(request, upload.MAX_UPLOAD_BYTES).form(
                max_files=upload.MAX_FILES, max_fields=1, max_part_size=1024) as form:
            items = form.multi_items()
            fields = [key for key, value in items if not isinstance(value, UploadFile)]
            if fields:
                return _error(400, f"/api/start: form field {fields[0][:40]!r}: the upload takes files only")
            parts = [(value.filename, value.file) for _, value in items]
            kept = await run_in_threadpool(upload.save, parts, data_root)
    except _TooLarge:
        return too_large
    except MultiPartException as exc:
        return _error(400, f"/api/start: not a readable upload: {exc.message}")
    except upload.UploadError as exc:
        return _error(exc.status, str(exc))
    except OSError as exc:
        return _error(507, f"/api/start: the upload could not be kept under the data root: {exc.strerror}")
    return await _bus(operator.start_uploaded, kept, params)


async def _bus(fn, *args) -> Response:
    """A bus query off the event loop; a refusal or a silent service becomes a JSON error."""
    from starlette.concurrency import run_in_threadpool

    try:
        return JSONResponse(await run_in_threadpool(fn, *args))
    except VrsimError as exc:
        return _error(502, str(exc))


def _error(status: int, message: str, headers: dict | None = None) -> Response:
    return JSONResponse({"error": message}, status_code=status, headers=headers)


def _login_form(message: str, status: int) -> Response:
    with open(os.path.join(STATIC, "login.html"), encoding="utf-8") as fh:
        html = fh.read().replace("<!--message-->", message)  # our own fixed sentences, never the request's
    return HTMLResponse(html, status_code=status, headers={"Cache-Control": "no-store"})


def _role(session, operator: Operator | None) -> str:
    """What the session may do here: operator only with an operator's login on a service that has one."""
    return "operator" if operator is not None and session.role == "operator" else "viewer"


def _other_site(request: Request, verb: str) -> Response | None:
    """403 for a request a page of another site made (its Origin is not ours)."""
    origin = request.headers.get("origin")
    if origin is not None and origin != f"{request.url.scheme}://{request.headers.get('host', '')}":
        return _error(403, f"/{verb}: refused a request from the page of another site ({origin[:80]})")
    return None


def _refuse_operator(request: Request, operator: Operator | None, verb: str) -> Response | None:
    """403 on a viewer service, for a viewer's session, for another site's page (without this any
    site open in the same browser could stop a run on 127.0.0.1), and without the session's CSRF
    token in ``X-CSRF-Token``."""
    if operator is None:
        return _error(403, f"/api/{verb}: this web service is a viewer (start it with --operator to "
                           "start and stop runs)")
    session = request.state.session
    if session.role != "operator":
        return _error(403, f"/api/{verb}: this login is a viewer's (log in as operator, or with the "
                           "token printed at start, to start and stop runs)")
    refused = _other_site(request, f"api/{verb}")
    if refused is not None:
        return refused
    if not csrf_ok(session, request.headers):
        return _error(403, f"/api/{verb}: missing or wrong X-CSRF-Token (the page sends its session's)")
    return None


async def _body(request: Request, limit: int) -> bytes | None:
    """The request body, or None beyond ``limit`` bytes (counted while reading, not trusted from
    Content-Length)."""
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            return None
        chunks.append(chunk)
    return b"".join(chunks)
