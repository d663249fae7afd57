"""The serving side every vrsim Zenoh service shares: selector parameters, a queryable that never
lets an exception escape, subscriber callbacks that report bad messages, liveliness and a service's
life from session to shutdown."""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass

from vrsim.common import ServiceError, VrsimError
from vrsim.services.bus.config import Keys, ZenohOptions, open_session
from vrsim.services.outputs.encode import dumps


# ---------------------------------------------------------------------------------------- errors
def _error_payload(message: str) -> bytes:
    return dumps({"error": message})


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


DEFAULT_MAX_BODY_BYTES = 8 * 1024 * 1024  # a lockstep pose batch is ~0.3 MB, a scenario at most 1 MB


def body_limit(max_bytes: int):
    """Decorate a handler whose key takes bodies larger than `DEFAULT_MAX_BODY_BYTES` (map/rate)."""

    def mark(fn):
        fn.max_body_bytes = max_bytes
        return fn

    return mark


@dataclass(frozen=True)
class Later:
    """What a handler returns when its reply takes long (building a world): `serve` runs ``work`` in a
    thread of its own and replies with its result (or its error) when done, so the queryable's other
    keys (``status``, ``stop``) keep answering meanwhile."""

    work: Callable[[], bytes]


Handler = Callable[[Params, bytes | None], "bytes | Later"]


def within(timeout_s: float, fn: Callable, what: str):
    """``fn()`` in a daemon thread; its result, or a `ServiceError` when it takes longer than ``timeout_s``
    (the thread cannot be killed: it finishes on its own and its result is dropped)."""
    done: list = []

    def run():
        try:
            done.append((True, fn()))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            done.append((False, exc))

    worker = threading.Thread(target=run, name="vrsim-within", daemon=True)
    worker.start()
    worker.join(timeout_s)
    if not done:
        raise ServiceError(f"{what}: took longer than {timeout_s:g} s; refused")
    ok, value = done[0]
    if not ok:
        raise value
    return value


def serve(session, namespace: str, handlers: dict[str, Handler], strip: str, service: str,
          hint: str | None = None):
    """Declare one queryable over ``namespace`` that dispatches on the key's tail after ``strip``.

    A handler takes (params, payload bytes or None) and returns the reply payload, or a `Later`. A
    body larger than the handler's limit (`body_limit`, default `DEFAULT_MAX_BODY_BYTES`) is refused
    before the handler sees it. A `VrsimError` (bad input) becomes an error reply
    ``{"error": message}``; any other exception also becomes one (prefixed "internal error",
    traceback on stderr) so no query is left unanswered and the service keeps serving. ``hint``
    replaces the list of keys in the unknown-key message.
    """

    def answer(query, key: str, work: Callable[[], "bytes | Later"]) -> None:
        try:
            reply = work()
            if isinstance(reply, Later):
                threading.Thread(target=answer, args=(query, key, reply.work), name=f"vrsim-{service}-later",
                                 daemon=True).start()
                return
            query.reply(query.key_expr, reply)
        except VrsimError as exc:
            _reply_err(query, str(exc))
        except Exception as exc:  # noqa: BLE001 - a bug must still answer, or the caller waits for nothing
            traceback.print_exc(file=sys.stderr)
            _reply_err(query, f"{key}: internal error in the {service} service: {type(exc).__name__}: {exc}")
        query.drop()  # answered: the querier's "no more replies" goes out now, not when Python collects it

    def on_query(query) -> None:
        key = str(query.key_expr)

        def work():
            tail = key[len(strip):] if key.startswith(strip) else key
            handler = handlers.get(tail)
            if handler is None:
                known = ", ".join(strip + t for t in sorted(handlers))
                raise ServiceError(f"{key}: unknown key ({hint or f'the {service} service serves {known}'})")
            limit = getattr(handler, "max_body_bytes", DEFAULT_MAX_BODY_BYTES)
            return handler(Params(key, query.parameters), payload_bytes(query.payload, key, limit))

        answer(query, key, work)

    return session.declare_queryable(namespace, on_query)


def payload_bytes(payload, key: str, max_bytes: int) -> bytes | None:
    """The body's bytes, refused by its size before it is copied or parsed."""
    if payload is None:
        return None
    size = len(payload)
    if size > max_bytes:
        raise ServiceError(f"{key}: a body of {size:,} bytes is over the {max_bytes:,}-byte limit of this "
                           "key")
    return payload.to_bytes()


def _reply_err(query, message: str) -> None:
    try:
        query.reply_err(_error_payload(message))
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


PARENT_ENV = "VRSIM_SERVE_PARENT"  # set by `vrsim serve all` for its children


def _parent_gone() -> Callable[[], bool] | None:
    """A check that a child of `vrsim serve all` uses to exit when its parent died without stopping it."""
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return None
    return lambda: os.getppid() != int(parent)


def run_service(name: str, options: ZenohOptions, declare: Callable, default_mode: str = "client",
                stop: threading.Event | None = None) -> None:
    """The life of one service: open a session (logged in as the user ``name`` unless ``--user`` says
    otherwise), ``declare(session)``, announce liveliness, serve until SIGINT/SIGTERM (or ``stop``),
    close. ``declare`` returns what to keep alive (queryables, ...)."""
    stop = stop or threading.Event()
    with open_session(options, default_mode, default_user=name) as session:
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
