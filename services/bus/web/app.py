"""The web side: the page, ``/events`` (Server-Sent Events, thinned) and the JSON API (docs/api.md).

Frames: one task closes a frame of the `LiveView` at most every `FRAME_S` when anything changed and
wakes the streams; each stream sends one event per frame at most (``hello`` to start over, else
``frame``: what changed since the frame it sent last). A browser slower than that skips frames: its
stream waits in `send` (uvicorn stops at 64 KB of unsent bytes), and its next event covers all it
missed, so nothing queues up per browser.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time

import orjson
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from common import VrsimError
from services.bus.web.bridge import RUN_ID, Bridge, Operator
from services.bus.web.live import FRAME_S, LiveView

STATIC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "web_static")
KEEPALIVE_S = 15.0  # a comment line this often: proxies keep the stream open, a gone browser is noticed
MAX_SCENARIO_BYTES = 1_000_000
LOOPBACK_HOSTS = ["127.0.0.1", "localhost"]


class _Frames:
    """Closes frames at most every `FRAME_S` and wakes the streams waiting for one."""

    def __init__(self, view: LiveView):
        self.view = view
        self.event = asyncio.Event()
        self.closing = False

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


def _sse(kind: str, doc: dict) -> bytes:
    """One event; ``sent_unix``: when it left (wall clock, s), for a client's own latency figures."""
    doc["sent_unix"] = time.time()
    return b"event: " + kind.encode() + b"\ndata: " + orjson.dumps(doc) + b"\n\n"


def create_app(view: LiveView, bridge: Bridge, operator: Operator | None,
               allowed_hosts: list[str] | None = None) -> Starlette:
    """The Starlette app. ``operator`` None: a viewer (start and stop answer 403);
    ``allowed_hosts``: Host headers accepted (against DNS rebinding on loopback; None: any)."""
    frames = _Frames(view)
    role = "operator" if operator is not None else "viewer"

    @contextlib.asynccontextmanager
    async def lifespan(app):
        frames.event = asyncio.Event()  # bound to uvicorn's loop
        task = asyncio.create_task(frames.run())
        try:
            yield
        finally:
            frames.closing = True
            frames.event.set()
            task.cancel()

    async def page(request: Request) -> Response:
        return FileResponse(os.path.join(STATIC, "index.html"), headers={"Cache-Control": "no-cache"})

    async def events(request: Request) -> Response:
        async def stream():
            loop = asyncio.get_running_loop()
            bridge.viewers += 1
            try:
                doc = view.hello()
                sent = loop.time()
                yield _sse("hello", doc)
                while not frames.closing:
                    if not await frames.next(doc["seq"]):
                        yield b": keepalive\n\n"
                        continue
                    # Events of one stream leave at least FRAME_S apart, also after a stall.
                    await asyncio.sleep(max(0.0, sent + FRAME_S - loop.time()))
                    if frames.closing:
                        return
                    doc = view.delta(doc["seq"], doc["epoch"])
                    sent = loop.time()
                    yield _sse(doc["type"], doc)
            finally:
                bridge.viewers -= 1

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def view_doc(request: Request) -> Response:
        current = view.map
        doc = {"role": role, "frame_s": FRAME_S, "run": view.run,
               "map": None if current is None else {
                   "version": current["version"], "info": current["info"], "grid": current["grid"].to_dict(),
                   "scale": bridge.map_scale, "png": f"/api/map.png?v={current['version']}"}}
        return JSONResponse(doc)

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
        body = await _body(request)
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
    return Starlette(routes=routes, middleware=middleware, lifespan=lifespan)


async def _bus(fn, *args) -> Response:
    """A bus query off the event loop; a refusal or a silent service becomes a JSON error."""
    from starlette.concurrency import run_in_threadpool

    try:
        return JSONResponse(await run_in_threadpool(fn, *args))
    except VrsimError as exc:
        return _error(502, str(exc))


def _error(status: int, message: str) -> Response:
    return JSONResponse({"error": message}, status_code=status)


def _refuse_operator(request: Request, operator: Operator | None, verb: str) -> Response | None:
    """403 for a viewer; 403 for a request a page of another site made (its Origin is not ours:
    without this any site open in the same browser could stop a run on 127.0.0.1)."""
    if operator is None:
        return _error(403, f"/api/{verb}: this web service is a viewer (start it with --operator to "
                           "start and stop runs)")
    origin = request.headers.get("origin")
    if origin is not None and origin != f"{request.url.scheme}://{request.headers.get('host', '')}":
        return _error(403, f"/api/{verb}: refused a request from the page of another site ({origin[:80]})")
    return None


async def _body(request: Request) -> bytes | None:
    """The request body, or None beyond `MAX_SCENARIO_BYTES` (counted while reading, not trusted
    from Content-Length)."""
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_SCENARIO_BYTES:
            return None
        chunks.append(chunk)
    return b"".join(chunks)
