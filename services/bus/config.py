"""What every vrsim Zenoh service shares: session configuration, key expressions, liveliness,
query handling that never lets an exception escape, and a client-side `request`.

Topology: one process is the router (``mode: "router"``, listening on 127.0.0.1 by default); the
services and `vrsim query` are clients connected to it (zenoh peers do not relay for each other, so
a router is what lets any process reach any other). ``vrsim serve all`` is the router; a single
``vrsim serve NAME`` connects to one unless given ``--listen`` (then it is a router itself).

Safe defaults: loopback only, multicast scouting off, shared memory off (under CPU load it can drop a
query), a fixed default port that ``--listen`` / ``--connect`` change, and ``--zenoh-config FILE`` for
anything else. Imports of zenoh happen inside functions so that ``vrsim --help`` stays light.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass

from common import ServiceError, VrsimError

DEFAULT_PORT = 7448  # zenohd's 7447 plus one, so a system zenohd does not collide with vrsim
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
DEFAULT_PREFIX = "vrsim"
DEFAULT_MACHINE = "tractor1"
QUERY_TIMEOUT_S = 10.0
SERVICES = ("map", "vehicle", "controller", "monitor", "scenario")
_BAD_KEY_CHARS = set("*$?#[] \t\r\n")


@dataclass(frozen=True)
class ZenohOptions:
    """How a process joins the vrsim Zenoh network (the ``--listen`` ... options)."""

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: str | None = None
    prefix: str = DEFAULT_PREFIX
    machine: str = DEFAULT_MACHINE

    def __post_init__(self):
        for name in ("prefix", "machine"):
            value = getattr(self, name)
            bad = not isinstance(value, str) or not value or _BAD_KEY_CHARS & set(value) \
                or value.startswith("/") or value.endswith("/") or "//" in value
            if bad or (name == "machine" and "/" in value):
                raise ServiceError(f"--{name} {value!r}: must be a non-empty key expression chunk"
                                   f"{'' if name == 'prefix' else ' without /'} and no * $ ? # or spaces")
        for endpoint in self.listen + self.connect:
            if "/" not in endpoint or endpoint.split("/", 1)[0] not in ("tcp", "udp", "quic", "tls",
                                                                        "unixsock-stream", "ws"):
                raise ServiceError(f"endpoint {endpoint!r}: expected PROTOCOL/ADDRESS, e.g. "
                                   f"{DEFAULT_ENDPOINT}")

    @property
    def keys(self) -> Keys:
        return Keys(self.prefix, self.machine)

    def config(self, default_mode: str):
        """A `zenoh.Config`: ``default_mode`` ("router" or "client") unless the flags say otherwise.

        ``--listen`` makes a router that listens there, ``--connect`` a client of that router;
        neither: a router on, or a client of, `DEFAULT_ENDPOINT`. A ``--zenoh-config`` file is the
        starting point and only the flags given explicitly override it.
        """
        import zenoh

        if self.config_file is not None:
            try:
                conf = zenoh.Config.from_file(self.config_file)
            except (zenoh.ZError, OSError, ValueError) as exc:
                raise ServiceError(f"--zenoh-config {self.config_file}: {zenoh_reason(exc)}") from None
        else:
            conf = zenoh.Config()
            conf.insert_json5("scouting/multicast/enabled", "false")
            conf.insert_json5("transport/shared_memory/enabled", "false")
        if self.listen:
            mode, listen, connect = "router", list(self.listen), list(self.connect)
        elif self.connect:
            mode, listen, connect = "client", [], list(self.connect)
        elif self.config_file is not None:
            return conf
        else:
            mode = default_mode
            listen, connect = ([DEFAULT_ENDPOINT], []) if mode == "router" else ([], [DEFAULT_ENDPOINT])
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("listen/endpoints", json.dumps(listen))
        conf.insert_json5("connect/endpoints", json.dumps(connect))
        return conf

    def describe(self, default_mode: str) -> str:
        if self.listen:
            return f"router on {', '.join(self.listen)}"
        if self.connect:
            return f"client of {', '.join(self.connect)}"
        if self.config_file:
            return f"as configured in {self.config_file}"
        role = "router on" if default_mode == "router" else "client of"
        return f"{role} {DEFAULT_ENDPOINT}"

    def child_args(self) -> list[str]:
        """Command-line options that make a child service a client of this process's router."""
        connect = self.connect or self.listen or self._config_listen() or (DEFAULT_ENDPOINT,)
        local = [ep.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for ep in connect]
        args = [a for ep in local for a in ("--connect", ep)]
        return args + ["--prefix", self.prefix, "--machine", self.machine]

    def _config_listen(self) -> tuple[str, ...]:
        """The router's listen endpoints in the ``--zenoh-config`` file, if it has one."""
        if self.config_file is None:
            return ()
        endpoints = json.loads(self.config("router").get_json("listen/endpoints"))
        if isinstance(endpoints, dict):  # zenoh's per-mode form {"router": [...], "peer": [...]}
            endpoints = endpoints.get("router", [])
        return tuple(endpoints)


def add_arguments(parser) -> None:
    """The Zenoh options every serving or querying command takes."""
    parser.add_argument("--listen", metavar="ENDPOINT", action="append", default=[],
                        help=f"be a router listening here (repeatable; e.g. {DEFAULT_ENDPOINT})")
    parser.add_argument("--connect", metavar="ENDPOINT", action="append", default=[],
                        help=f"connect to a router here (repeatable; default {DEFAULT_ENDPOINT})")
    parser.add_argument("--zenoh-config", metavar="FILE", default=None,
                        help="zenoh JSON5 configuration file (routers, other hosts, ...)")
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"key prefix (default {DEFAULT_PREFIX})")
    parser.add_argument("--machine", default=DEFAULT_MACHINE,
                        help=f"machine name in the keys (default {DEFAULT_MACHINE})")


def options_from_args(args) -> ZenohOptions:
    return ZenohOptions(listen=tuple(args.listen), connect=tuple(args.connect),
                        config_file=args.zenoh_config, prefix=args.prefix, machine=args.machine)


def open_session(options: ZenohOptions, default_mode: str = "client"):
    """`zenoh.open` with a message that says where it tried to connect."""
    import zenoh

    try:
        return zenoh.open(options.config(default_mode))
    except zenoh.ZError as exc:
        where = options.describe(default_mode)
        raise ServiceError(f"cannot open a zenoh session ({where}): {zenoh_reason(exc)}; "
                           "is `vrsim serve all` running, or is the port taken?") from None


def zenoh_reason(exc: Exception) -> str:
    """A zenoh error on one line, without the Rust source locations it carries."""
    text = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", str(exc))
    return " ".join(line.strip(" |") for line in text.splitlines() if line.strip(" |"))


@dataclass(frozen=True)
class Keys:
    """Every key expression of the vrsim API (docs/api.md), for one prefix and machine."""

    prefix: str = DEFAULT_PREFIX
    machine: str = DEFAULT_MACHINE

    def _m(self, tail: str) -> str:
        return f"{self.prefix}/{self.machine}/{tail}"

    # map service
    @property
    def map_ns(self) -> str:
        return f"{self.prefix}/map/**"

    @property
    def map_info(self) -> str:
        return f"{self.prefix}/map/info"

    @property
    def map_rate(self) -> str:
        return f"{self.prefix}/map/rate"

    @property
    def map_load(self) -> str:
        return f"{self.prefix}/map/load"

    # publications
    @property
    def pose(self) -> str:
        return self._m("pose")

    @property
    def shaft(self) -> str:
        return self._m("shaft")

    @property
    def rate(self) -> str:
        return self._m("rate")

    # monitor: one chunk under the machine, so `report` and unknown keys share one queryable
    @property
    def machine_ns(self) -> str:
        return self._m("*")

    @property
    def report(self) -> str:
        return self._m("report")

    @property
    def monitor_ns(self) -> str:
        return self._m("monitor/**")

    @property
    def monitor_load(self) -> str:
        return self._m("monitor/load")

    @property
    def monitor_status(self) -> str:
        return self._m("monitor/status")

    # controller
    @property
    def control_ns(self) -> str:
        return self._m("control/**")

    @property
    def control_step(self) -> str:
        return self._m("control/step")

    @property
    def control_load(self) -> str:
        return self._m("control/load")

    # vehicle
    @property
    def vehicle_ns(self) -> str:
        return self._m("vehicle/**")

    def vehicle(self, verb: str) -> str:
        return self._m(f"vehicle/{verb}")

    # scenario control
    @property
    def scenario_ns(self) -> str:
        return f"{self.prefix}/scenario/**"

    def scenario(self, verb: str) -> str:
        return f"{self.prefix}/scenario/{verb}"

    @property
    def top_ns(self) -> str:
        return f"{self.prefix}/*"

    # liveliness
    def alive(self, service: str) -> str:
        return f"{self.prefix}/alive/{service}"

    @property
    def alive_all(self) -> str:
        return f"{self.prefix}/alive/*"


# ---------------------------------------------------------------------------------------- errors
def error_payload(message: str) -> bytes:
    return json.dumps({"error": message}).encode()


def error_message(payload: bytes) -> str:
    """The message of an error reply; non-JSON error payloads (zenoh's own, e.g. a timeout) verbatim."""
    text = payload.decode("utf-8", "replace")
    try:
        doc = json.loads(text)
    except ValueError:
        return text
    return doc["error"] if isinstance(doc, dict) and isinstance(doc.get("error"), str) else text


class Params:
    """Selector parameters of one query, with checks that name the key, parameter and value."""

    def __init__(self, key: str, parameters):
        self.key = key
        self.values: dict[str, str] = {}
        for name, value in parameters:  # zenoh.Parameters iterates (name, value) pairs
            if name in self.values:
                raise ServiceError(f"{key}: parameter {name} given twice")
            self.values[name] = value

    def only(self, *names: str) -> None:
        unknown = sorted(set(self.values) - set(names))
        if unknown:
            known = ", ".join(names) or "none"
            raise ServiceError(f"{self.key}: unknown parameter {unknown[0]!r} (known: {known})")

    def has(self, name: str) -> bool:
        return name in self.values

    def text(self, name: str, default: str | None = None) -> str | None:
        return self.values.get(name, default)

    def number(self, name: str, lo: float | None = None, hi: float | None = None,
               default: float | None = None) -> float:
        """A finite number within [lo, hi]; ``default`` None means the parameter is required."""
        if name not in self.values:
            if default is None:
                raise ServiceError(f"{self.key}: missing parameter {name}")
            return default
        raw = self.values[name]
        try:
            value = float(raw)
        except ValueError:
            raise ServiceError(f"{self.key}: parameter {name}={raw!r} is not a number") from None
        if not math.isfinite(value):
            raise ServiceError(f"{self.key}: parameter {name}={raw!r} must be finite")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ServiceError(f"{self.key}: parameter {name}={raw!r} is out of range "
                               f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]")
        return value

    def integer(self, name: str, lo: int, hi: int, default: int) -> int:
        value = self.number(name, lo, hi, float(default))
        if value != int(value):
            raise ServiceError(f"{self.key}: parameter {name}={self.values[name]!r} must be whole")
        return int(value)


Handler = Callable[[Params, bytes | None], bytes]


def serve(session, namespace: str, handlers: dict[str, Handler], strip: str, service: str,
          hint: str | None = None):
    """Declare one queryable over ``namespace`` that dispatches on the key's tail after ``strip``.

    A handler takes (params, payload bytes or None) and returns the reply payload. A `VrsimError`
    (bad input) becomes an error reply ``{"error": message}``; any other exception also becomes one
    (prefixed "internal error", traceback on stderr) so no query is left unanswered and the service
    keeps serving. ``hint`` replaces the list of keys in the unknown-key message.
    """

    def on_query(query) -> None:
        key = str(query.key_expr)
        try:
            tail = key[len(strip):] if key.startswith(strip) else key
            handler = handlers.get(tail)
            if handler is None:
                known = ", ".join(strip + t for t in sorted(handlers))
                raise ServiceError(f"{key}: unknown key ({hint or f'the {service} service serves {known}'})")
            payload = query.payload.to_bytes() if query.payload is not None else None
            reply = handler(Params(key, query.parameters), payload)
            query.reply(query.key_expr, reply)
        except VrsimError as exc:
            _reply_err(query, str(exc))
        except Exception as exc:  # noqa: BLE001 - a bug must still answer, or the caller waits for nothing
            traceback.print_exc(file=sys.stderr)
            _reply_err(query, f"{key}: internal error in the {service} service: {type(exc).__name__}: {exc}")

    return session.declare_queryable(namespace, on_query)


def _reply_err(query, message: str) -> None:
    try:
        query.reply_err(error_payload(message))
    except Exception:  # noqa: BLE001 - the querier may be gone; nothing else to tell
        traceback.print_exc(file=sys.stderr)


def guarded(what: str, fn: Callable) -> Callable:
    """A subscriber callback that prints (instead of zenoh silently swallowing) what went wrong."""

    def callback(sample) -> None:
        try:
            fn(sample)
        except VrsimError as exc:
            print(f"vrsim {what}: dropped a bad message on {sample.key_expr}: {exc}", file=sys.stderr)
        except Exception:  # noqa: BLE001
            print(f"vrsim {what}: internal error handling {sample.key_expr}:", file=sys.stderr)
            traceback.print_exc(file=sys.stderr)

    return callback


# ---------------------------------------------------------------------------------------- client
def request(session, selector: str, payload: bytes | None = None, timeout_s: float = QUERY_TIMEOUT_S,
            what: str | None = None) -> bytes:
    """One query, one reply: the reply's payload, or a `ServiceError` that says what was waited for.

    Raises when no service serves the key (zenoh answers at once with no reply), when the reply does
    not come within ``timeout_s``, or when the service replied with an error (its message).
    """
    import zenoh

    what = what or selector
    kwargs = {"timeout": timeout_s, "target": zenoh.QueryTarget.BEST_MATCHING}
    if payload is not None:
        kwargs["payload"] = payload
    try:
        replies = list(session.get(selector, **kwargs))
    except zenoh.ZError as exc:  # e.g. an invalid key expression ("$", "#" ...)
        raise ServiceError(f"{what}: {zenoh_reason(exc)}") from None
    for reply in replies:
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
    if not replies:
        raise ServiceError(f"{what}: no reply: no service serves this key (is it running? "
                           "`vrsim query <prefix>/scenario/status` lists the services alive)")
    message = error_message(replies[0].err.payload.to_bytes())
    if message.lower().startswith("timeout"):
        raise ServiceError(f"{what}: no reply within {timeout_s:g} s (service busy or hung)")
    raise ServiceError(message)


def request_json(session, selector: str, payload: bytes | None = None,
                 timeout_s: float = QUERY_TIMEOUT_S, what: str | None = None):
    raw = request(session, selector, payload, timeout_s, what)
    try:
        return json.loads(raw)
    except ValueError:
        raise ServiceError(f"{what or selector}: reply is not JSON: {raw[:80]!r}") from None


def alive_services(session, keys: Keys, timeout_s: float = 1.0) -> list[str]:
    """Names of the services whose liveliness token is declared right now."""
    names = []
    base = keys.alive("")
    for reply in session.liveliness().get(keys.alive_all, timeout=timeout_s):
        if reply.ok is not None:
            key = str(reply.ok.key_expr)
            names.append(key[len(base):] if key.startswith(base) else key)
    return sorted(set(names))


def declare_alive(session, keys: Keys, service: str):
    return session.liveliness().declare_token(keys.alive(service))


# ---------------------------------------------------------------------------------------- lifetime
def wait_for_signal(stop: threading.Event, also: Callable[[], bool] | None = None,
                    poll_s: float = 0.2) -> None:
    """Block until SIGINT/SIGTERM (or ``stop`` is set, or ``also()`` turns true)."""

    def handler(signum, frame):
        stop.set()

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not stop.wait(poll_s):
            if also is not None and also():
                break
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


def dumps(doc) -> bytes:
    """JSON reply bytes; NaN and infinities become null (JSON has no NaN)."""
    return json.dumps(_finite(doc), separators=(",", ":")).encode()


def _finite(doc):
    if isinstance(doc, float):
        return doc if math.isfinite(doc) else None
    if isinstance(doc, dict):
        return {k: _finite(v) for k, v in doc.items()}
    if isinstance(doc, (list, tuple)):
        return [_finite(v) for v in doc]
    return doc


PARENT_ENV = "VRSIM_SERVE_PARENT"  # set by `vrsim serve all` for its children


def _parent_gone() -> Callable[[], bool] | None:
    """A check that a child of `vrsim serve all` uses to exit when its parent died without stopping it."""
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return None
    return lambda: os.getppid() != int(parent)


def run_service(name: str, options: ZenohOptions, declare: Callable, default_mode: str = "client",
                stop: threading.Event | None = None) -> None:
    """The life of one service: open a session, ``declare(session)``, announce liveliness, serve until
    SIGINT/SIGTERM (or ``stop``), close. ``declare`` returns what to keep alive (queryables, ...)."""
    stop = stop or threading.Event()
    with open_session(options, default_mode) as session:
        keep = declare(session)
        token = declare_alive(session, options.keys, name)
        print(f"vrsim serve {name}: ready ({options.describe(default_mode)}, prefix {options.prefix})",
              file=sys.stderr, flush=True)
        wait_for_signal(stop, also=_parent_gone())
        token.undeclare()
        for obj in keep or ():
            close = getattr(obj, "undeclare", None) or getattr(obj, "close", None)
            if close is not None:
                close()
