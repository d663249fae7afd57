"""The web service: a page that shows a run as it happens (``vrsim serve web``).

A viewer on the bus (it subscribes and queries; its only writes, start and stop, go through
`bridge.Operator` and only when it is given one) and a small HTTP server (Starlette on uvicorn) on
127.0.0.1:8448 unless told otherwise. Modules: `live` (the state the page shows, pure), `picture`
(colour scale, the prescription as PNG), `bridge` (the bus side), `app` (the HTTP side); the page
itself is ``services/bus/web_static/`` (plain JavaScript and canvas, no library, no network),
`auth` says who may ask (a login token printed with the page's URL, or a bus user's password), and
`guard` how many connections may be open and for how long. See docs/api.md for ``/events`` and the
JSON API, docs/security.md for the page's defences.

Keep imports here light: ``vrsim serve`` imports this package only to call `main`.
"""

from __future__ import annotations

import os
import socket
import sys
import threading
import time

from vrsim.common import ServiceError

DEFAULT_LISTEN = "127.0.0.1:8448"
READY_TIMEOUT_S = 10.0
LOOPBACK = ("127.0.0.1", "localhost", "::1")
WILDCARDS = ("0.0.0.0", "::")


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
    """A listening socket, bound before anything else starts, so a taken port is a clear error; its
    ``accept`` admits connections through a `guard.Door` once `_HttpServer` gives it one."""
    from vrsim.services.bus.web.guard import BACKLOG, Listener

    try:
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = Listener(info[0], socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(info[4])
        sock.listen(BACKLOG)
    except OSError as exc:
        raise ServiceError(f"serve web: cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


class _HttpServer:
    """uvicorn serving ``app`` on ``sock`` (from `_bind`) in a thread, behind a `guard.Door` (``door``,
    else one for this process's file limit); ``stop`` is set if it ends by itself."""

    def __init__(self, app, sock: socket.socket, stop: threading.Event, tls: tuple[str, str] | None = None,
                 door=None):
        import logging

        from vrsim.services.bus.web import guard

        self.door = door or guard.Door(guard.cap_for(guard.raise_file_limit()), tls=tls is not None)
        sock.door = self.door
        self.server = guard.Server(guard.config(app, self.door, tls), self.door)
        self.log = logging.getLogger("uvicorn.error")  # its per-request warnings: counted by the door
        self.log.addFilter(self.door.log_filter)
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
        self.log.removeFilter(self.door.log_filter)


def _allowed_hosts(host: str) -> list[str]:
    """Host headers the page answers when listening on ``host`` (others: 400, against DNS rebinding):
    the loopback names, and the address listened on or, on a wildcard, this machine's names and
    addresses."""
    from vrsim.services.bus.web.app import LOOPBACK_HOSTS

    names = [*LOOPBACK_HOSTS]
    if host not in WILDCARDS:
        return [*names, f"[{host}]" if ":" in host else host]  # Host headers bracket IPv6 addresses
    names += [socket.gethostname(), socket.getfqdn(), *(["[::1]"] if host == "::" else [])]
    try:
        names += socket.gethostbyname_ex(socket.gethostname())[2]
    except OSError:
        pass  # no address for the name: reach it by an address given with --listen instead
    return list(dict.fromkeys(names))


def check_listen(host: str, port: int, tls: bool, insecure: bool) -> None:
    """Refuse a page beyond loopback without TLS on a secure bus (the page takes the bus's certificate)."""
    if host not in LOOPBACK and not tls and not insecure:
        raise ServiceError(f"web page on {host}:{port}: beyond loopback the page needs TLS, with "
                           "the bus's certificates (start the bus with --tls: `vrsim serve all --tls --web "
                           "...`), or listen on 127.0.0.1")


def _page_tls(config, host: str, port: int):
    """(the state folder's passwords or None, (certificate, key) for TLS or None) for a page on
    ``host``: beyond loopback the page is served over TLS with the bus's certificate (its CA signed
    it: ``vrsim serve all --tls``); an ``--insecure`` bus has neither, and says so."""
    from vrsim.services.bus import security

    if config.zenoh.insecure:
        if host not in LOOPBACK:
            print(f"vrsim serve web: WARNING: --insecure: the page on {host}:{port} is plain HTTP beyond "
                  "this machine; its login token crosses the network in clear", file=sys.stderr, flush=True)
        return None, None
    if config.zenoh.config_file is not None and not os.path.isdir(config.zenoh.state_dir):
        check_listen(host, port, tls=False, insecure=False)  # logged in by the file: no state folder
        return None, None  # the token only
    state = security.load_state(config.zenoh.state_dir)
    if host in LOOPBACK:
        return state.passwords, None
    check_listen(host, port, state.tls, insecure=False)
    return state.passwords, (state.tls_file("router.pem"), state.tls_file("router-key.pem"))


def main(config, stop: threading.Event | None = None) -> int:
    """Serve the page until SIGINT/SIGTERM (or ``stop``): ``config.web_listen`` (default
    `DEFAULT_LISTEN`), a viewer on ``config.zenoh``, start/stop with ``config.operator``; prints
    the page's URL with its login token."""
    from vrsim.services.bus.dataroot import DataRoot
    from vrsim.services.bus.serving import run_service
    from vrsim.services.bus.web.app import create_app
    from vrsim.services.bus.web.auth import Logins
    from vrsim.services.bus.web.bridge import Bridge, Operator
    from vrsim.services.bus.web.live import LiveView

    host, port = parse_listen(config.web_listen or DEFAULT_LISTEN)
    sock = _bind(host, port)  # first: a taken port is the clearest error
    passwords, tls = _page_tls(config, host, port)
    stop = stop or threading.Event()
    if host not in LOOPBACK:
        print(f"vrsim serve web: listening on {host}:{port}, beyond this machine: anyone who reaches it "
              "may try to log in", file=sys.stderr, flush=True)

    def declare(session):
        view = LiveView()
        bridge = Bridge(session, config.zenoh.keys, view, data=DataRoot.of(config))
        subscribers = bridge.declare()
        operator = Operator(config.operator) if config.operator is not None else None
        logins = Logins("operator" if operator else "viewer", passwords, f"vrsim_session_{port}",
                        secure=tls is not None)
        http = _HttpServer(create_app(view, bridge, operator, logins, _allowed_hosts(host)), sock, stop, tls)
        bridge.start()
        role = "operator: start and stop allowed" if operator else "viewer"
        shown = {"0.0.0.0": "127.0.0.1", "::": "[::1]"}.get(host, f"[{host}]" if ":" in host else host)
        print(f"vrsim serve web: page at {'https' if tls else 'http'}://{shown}:{port}/?token={logins.token} "
              f"({role}; or log in at /login with a user's password from the state folder)",
              file=sys.stderr, flush=True)
        return [http, bridge, *subscribers, *([operator] if operator else [])]

    try:
        run_service("web", config.zenoh, declare, stop=stop)
    finally:
        sock.close()
    return 0
