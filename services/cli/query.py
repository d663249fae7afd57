"""`vrsim query KEY [NAME=VALUE ...]`: ask a vrsim Zenoh service and print its reply.

KEY may leave out the prefix (``map/rate`` means ``vrsim/map/rate``) and the machine (``report``
means ``vrsim/tractor1/report``). The reply is printed as the service sent it (one JSON document); an
error reply prints ``vrsim query: error: MESSAGE`` on stderr and exits 2. ``--watch`` subscribes to a
published key (pose, shaft, rate) instead and prints ``--count`` samples, one per line.

It logs in as ``operator`` (``--user``) with the credentials of the state folder (``--state-dir``,
default ``.vrsim``) that ``vrsim serve all`` wrote, and connects where that router listens.
"""

from __future__ import annotations

import math
import sys

from vrsim.common import ServiceError, files
from vrsim.services.bus.client import request
from vrsim.services.bus.config import (
    ACCEPT_TIMEOUT_S,
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
    parser.add_argument("--timeout", type=float, default=None, metavar="S",
                        help=f"seconds to wait for the reply (default {QUERY_TIMEOUT_S:g}; "
                             f"{ACCEPT_TIMEOUT_S:g} for scenario/start, which replies once it has checked "
                             "the scenario and accepted the run)")
    parser.add_argument("--watch", action="store_true", help="subscribe to KEY and print samples")
    parser.add_argument("--count", type=int, default=1, metavar="N",
                        help="--watch: samples to print (default 1)")
    add_arguments(parser, user_help="log in as this user: operator (default), viewer, ...")


def _full_key(key: str, keys: Keys) -> str:
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


def _selector(key: str, params: list[str]) -> str:
    pairs = []
    for item in params:
        name, sep, value = item.partition("=")
        if not sep or not name or any(c in item for c in ";?#"):
            raise ServiceError(f"parameter {item!r}: expected NAME=VALUE without ; ? or #")
        pairs.append(f"{name}={value}")
    return key + ("?" + ";".join(pairs) if pairs else "")


def _body(path: str | None) -> bytes | None:
    """The body: a regular file or standard input, at most `MAX_BODY_BYTES` (what the router passes)."""
    from vrsim.services.bus.security import MAX_BODY_BYTES

    if path is None:
        return None
    if path != "-":
        return files.read_bytes(path, "query body", ServiceError, limit=MAX_BODY_BYTES)
    data = sys.stdin.buffer.read(MAX_BODY_BYTES + 1)
    if len(data) > MAX_BODY_BYTES:
        raise ServiceError(f"--body -: standard input holds more than the {MAX_BODY_BYTES:,} bytes a body "
                           "may have")
    return data


def _default_timeout(key: str, keys: Keys) -> float:
    """What ``key`` takes to answer: scenario/start builds the scenario's world and checks the services
    before it replies (`ACCEPT_TIMEOUT_S`), every other key answers at once (`QUERY_TIMEOUT_S`)."""
    return ACCEPT_TIMEOUT_S if key == keys.scenario("start") else QUERY_TIMEOUT_S


def run(args) -> int:
    if args.timeout is not None and not 0 < args.timeout < math.inf:
        raise ServiceError(f"--timeout {args.timeout}: must be a finite number > 0")
    if args.count < 1:
        raise ServiceError(f"--count {args.count}: must be >= 1")
    if args.watch and (args.params or args.body is not None):
        raise ServiceError("--watch subscribes to KEY: it takes no NAME=VALUE parameters and no --body")
    options = options_from_args(args)
    key = _full_key(args.key, options.keys)
    if args.timeout is None:
        args.timeout = _default_timeout(key, options.keys)
    body = _body(args.body)
    user = None if options.insecure else options.user or "operator"
    with open_session(options, "client", default_user="operator") as session:
        if args.watch:
            return _watch(session, key, args.count, args.timeout)
        reply = request(session, _selector(key, args.params), body, args.timeout, what=key, user=user)
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
