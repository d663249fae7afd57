"""The web service: a page that shows a run as it happens (``vrsim serve web``).

A viewer on the bus (it subscribes and queries; its only writes, start and stop, go through
`bridge.Operator` and only when it is given one) and a small HTTP server (Starlette on uvicorn) on
127.0.0.1:8448 unless told otherwise. Modules: `live` (the state the page shows, pure), `picture`
(colour scale, the prescription as PNG), `bridge` (the bus side), `app` (the HTTP side); the page
itself is ``services/bus/web_static/`` (plain JavaScript and canvas, no library, no network). See
docs/api.md for ``/events`` and the JSON API.

Keep imports here light: ``vrsim serve`` imports this package only to call `main`.
"""

from __future__ import annotations

import socket
import sys
import threading
import time

from common import ServiceError

DEFAULT_LISTEN = "127.0.0.1:8448"
READY_TIMEOUT_S = 10.0


def parse_listen(text: str, flag: str = "serve web: --listen") -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6) -> (host, port), refusing anything else (the message
    names ``flag``)."""
    host, sep, port = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or "/" in text or not port.isdigit() or not 0 < int(port) < 65536:
        raise ServiceError(f"{flag} {text!r}: expected HOST:PORT, e.g. {DEFAULT_LISTEN} "
                           "(the web service is a client of the zenoh router: --connect says where that is)")
    return host, int(port)


def _bind(host: str, port: int) -> socket.socket:
    """A listening socket, bound before anything else starts, so a taken port is a clear error."""
    try:
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(info[0], socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(info[4])
        sock.listen(128)
    except OSError as exc:
        raise ServiceError(f"serve web: cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


class _HttpServer:
    """uvicorn serving ``app`` on ``sock`` in a thread; ``stop`` is set if it ends by itself."""

    def __init__(self, app, sock: socket.socket, stop: threading.Event):
        import uvicorn

        self.server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False,
                                                    timeout_graceful_shutdown=1, lifespan="on"))
        self.thread = threading.Thread(target=self._run, args=(sock, stop), name="vrsim-web-http",
                                       daemon=True)
        self.thread.start()
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise ServiceError("serve web: the HTTP server did not start (see the lines above)")
            time.sleep(0.02)

    def _run(self, sock, stop: threading.Event) -> None:
        try:
            self.server.run(sockets=[sock])
        finally:
            stop.set()

    def close(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=5.0)


def main(config, stop: threading.Event | None = None) -> int:
    """Serve the page until SIGINT/SIGTERM (or ``stop``): ``config.web_listen`` (default
    `DEFAULT_LISTEN`), a viewer on ``config.zenoh``, start/stop with ``config.operator``."""
    from services.bus.dataroot import DataRoot
    from services.bus.serving import run_service
    from services.bus.web.app import LOOPBACK_HOSTS, create_app
    from services.bus.web.bridge import Bridge, Operator
    from services.bus.web.live import LiveView

    host, port = parse_listen(config.web_listen or DEFAULT_LISTEN)
    loopback = host in ("127.0.0.1", "localhost", "::1")
    sock = _bind(host, port)
    stop = stop or threading.Event()
    if not loopback:
        print(f"vrsim serve web: listening on {host}:{port}, beyond this machine: anyone who reaches it "
              "sees the runs", file=sys.stderr, flush=True)

    def declare(session):
        view = LiveView()
        bridge = Bridge(session, config.zenoh.keys, view, data=DataRoot.of(config))
        subscribers = bridge.declare()
        operator = Operator(config.operator) if config.operator is not None else None
        allowed = [*LOOPBACK_HOSTS, f"[{host}]" if ":" in host else host] if loopback else None
        http = _HttpServer(create_app(view, bridge, operator, allowed), sock, stop)
        bridge.start()
        role = "operator: start and stop allowed" if operator else "viewer"
        shown = f"[{host}]" if ":" in host else host
        print(f"vrsim serve web: page at http://{shown}:{port}/ ({role})", file=sys.stderr, flush=True)
        return [http, bridge, *subscribers, *([operator] if operator else [])]

    try:
        run_service("web", config.zenoh, declare, stop=stop)
    finally:
        sock.close()
    return 0
