"""How a vrsim process joins the Zenoh network: options, the session, the key expressions, and
`ServiceConfig`, the one argument every service's ``main`` takes.

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
import re
from dataclasses import dataclass

from common import ServiceError

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

    @property
    def monitor_run(self) -> str:
        return self._m("monitor/run")

    @property
    def monitor_records(self) -> str:
        return self._m("monitor/records")

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


@dataclass(frozen=True)
class ServiceConfig:
    """What ``vrsim serve NAME`` hands a service's ``main(config, stop=None) -> int``: how to join the
    network, and the settings of the services that take any (the others ignore them)."""

    zenoh: ZenohOptions
    scenario: str | None = None  # map: serve this scenario's prescription (None: the built-in default)
    map_file: str | None = None  # map: serve this file instead (fixed: scenario control cannot swap it)
    rate_field: str | None = None
    cell_size_m: float | None = None
    crs: str | None = None
    db: str | None = None  # monitor: its SQLite file (None: runs/monitor-<prefix>-<machine>.sqlite)
    web_listen: str | None = None  # web: HOST:PORT of the page (None: 127.0.0.1:8448)
    operator: ZenohOptions | None = None  # web: the session that may start and stop runs (None: viewer)
    # controller: folders whose Python files a scenario's [controller] kind = "python" may run (a
    # scenario comes over the bus, so by default no user code runs; absolute paths)
    user_code_dirs: tuple[str, ...] = ()
