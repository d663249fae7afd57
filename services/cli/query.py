"""`vrsim query KEY [NAME=VALUE ...]`: ask a vrsim Zenoh service and print its reply.

KEY may leave out the prefix (``map/rate`` means ``vrsim/map/rate``) and the machine (``report``
means ``vrsim/tractor1/report``). The reply is printed as the service sent it (one JSON document); an
error reply prints ``vrsim query: error: MESSAGE`` on stderr and exits 2. ``--watch`` subscribes to a
published key (pose, shaft, rate) instead and prints ``--count`` samples, one per line.
"""

from __future__ import annotations

import math
import sys

from common import ServiceError
from services.bus.client import request
from services.bus.config import (
    QUERY_TIMEOUT_S,
    Keys,
    add_arguments,
    open_session,
    options_from_args,
    zenoh_reason,
)

HELP = "query a vrsim Zenoh service (e.g. `vrsim query map/rate lat=52.1 lon=11.6`) and print the reply"
MACHINE_KEYS = ("report", "pose", "shaft", "rate", "control", "vehicle", "monitor")  # first chunk


def configure(parser) -> None:
    parser.add_argument("key", help="key expression, e.g. map/info, map/rate, scenario/status, report")
    parser.add_argument("params", nargs="*", metavar="NAME=VALUE", help="selector parameters")
    parser.add_argument("--body", metavar="FILE", default=None,
                        help="send this file as the query's body ('-': standard input)")
    parser.add_argument("--timeout", type=float, default=QUERY_TIMEOUT_S, metavar="S",
                        help=f"seconds to wait for the reply (default {QUERY_TIMEOUT_S:g})")
    parser.add_argument("--watch", action="store_true", help="subscribe to KEY and print samples")
    parser.add_argument("--count", type=int, default=1, metavar="N",
                        help="--watch: samples to print (default 1)")
    add_arguments(parser)


def full_key(key: str, keys: Keys) -> str:
    """KEY with the prefix (and, for the per-machine keys, the machine) filled in."""
    key = key.strip("/")
    if not key:
        raise ServiceError("KEY: empty key expression")
    if key == keys.prefix or key.startswith(keys.prefix + "/"):
        return key
    first = key.split("/", 1)[0]
    if first in MACHINE_KEYS:
        return f"{keys.prefix}/{keys.machine}/{key}"
    return f"{keys.prefix}/{key}"


def selector(key: str, params: list[str]) -> str:
    pairs = []
    for item in params:
        name, sep, value = item.partition("=")
        if not sep or not name or any(c in item for c in ";?#"):
            raise ServiceError(f"parameter {item!r}: expected NAME=VALUE without ; ? or #")
        pairs.append(f"{name}={value}")
    return key + ("?" + ";".join(pairs) if pairs else "")


def _body(path: str | None) -> bytes | None:
    if path is None:
        return None
    if path == "-":
        return sys.stdin.buffer.read()
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise ServiceError(f"--body {path}: cannot read: {exc.strerror}") from None


def run(args) -> int:
    if not 0 < args.timeout < math.inf:
        raise ServiceError(f"--timeout {args.timeout}: must be a finite number > 0")
    if args.count < 1:
        raise ServiceError(f"--count {args.count}: must be >= 1")
    if args.watch and (args.params or args.body is not None):
        raise ServiceError("--watch subscribes to KEY: it takes no NAME=VALUE parameters and no --body")
    options = options_from_args(args)
    key = full_key(args.key, options.keys)
    body = _body(args.body)
    with open_session(options, "client") as session:
        if args.watch:
            return _watch(session, key, args.count, args.timeout)
        reply = request(session, selector(key, args.params), body, args.timeout, what=key)
    sys.stdout.write(reply.decode("utf-8", "replace").rstrip("\n") + "\n")
    return 0


def _watch(session, key: str, count: int, timeout_s: float) -> int:
    import queue

    import zenoh

    got: queue.Queue = queue.Queue()
    try:
        sub = session.declare_subscriber(key, lambda sample: got.put(sample.payload.to_bytes()))
    except zenoh.ZError as exc:  # e.g. an invalid key expression
        raise ServiceError(f"{key}: {zenoh_reason(exc)}") from None
    try:
        for _ in range(count):
            try:
                payload = got.get(timeout=timeout_s)
            except queue.Empty:
                raise ServiceError(f"{key}: no sample within {timeout_s:g} s (is a run going?)") from None
            sys.stdout.write(payload.decode("utf-8", "replace") + "\n")
            sys.stdout.flush()
    finally:
        sub.undeclare()
    return 0
