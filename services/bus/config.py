"""How a vrsim process joins the Zenoh network: options, the session, the key expressions, and
`ServiceConfig`, the one argument every service's ``main`` takes.

Topology: one process is the router (``mode: "router"``, listening on 127.0.0.1 by default); the
services and `vrsim query` are clients connected to it (zenoh peers do not relay for each other, so
a router is what lets any process reach any other). ``vrsim serve all`` is the router; a single
``vrsim serve NAME`` connects to one unless given ``--listen`` (then it is a router itself).

Safe defaults: loopback only, multicast scouting off, shared memory off (under CPU load it can drop a
query), a fixed default port that ``--listen`` / ``--connect`` change, and ``--zenoh-config FILE`` for
anything else. Secure by default: a router enforces `services.bus.security` and a client logs in with
the credentials of the private state folder; ``--insecure`` opens the bus on purpose. Imports of
zenoh happen inside functions so that ``vrsim --help`` stays light.
"""

from __future__ import annotations

import json
import os
import re
import sys
from dataclasses import dataclass

from vrsim.common import ServiceError

DEFAULT_PORT = 7448  # zenohd's 7447 plus one, so a system zenohd does not collide with vrsim
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
DEFAULT_PREFIX = "vrsim"
DEFAULT_MACHINE = "tractor1"
QUERY_TIMEOUT_S = 10.0
# What a client waits for scenario/start's reply: it comes once the scenario is built (at most
# `services.bus.scenario.BUILD_TIMEOUT_S`, 60 s) and checked, with room for a busy machine.
ACCEPT_TIMEOUT_S = 120.0
SERVICES = ("map", "vehicle", "controller", "monitor", "scenario")
_BAD_KEY_CHARS = set("*$?#[] \t\r\n")


DEFAULT_STATE_DIR = ".vrsim"


@dataclass(frozen=True)
class ZenohOptions:
    """How a process joins the vrsim Zenoh network (the ``--listen`` ... options).

    Secure unless ``insecure``: a router enforces `services.bus.security` (credentials and access
    rules from the private ``state_dir``, TLS with ``tls``), a client logs in as ``user`` (None: the
    caller's default, the service's own name or ``operator``). ``ZenohOptions(user="web")`` is all a
    program beside ``vrsim serve all`` needs to log in as ``web``.
    """

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: str | None = None
    prefix: str = DEFAULT_PREFIX
    machine: str = DEFAULT_MACHINE
    state_dir: str = DEFAULT_STATE_DIR
    user: str | None = None
    insecure: bool = False
    tls: bool = False

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

    @property
    def default_endpoint(self) -> str:
        return DEFAULT_ENDPOINT.replace("tcp/", "tls/") if self.tls else DEFAULT_ENDPOINT

    def config(self, default_mode: str, default_user: str = "operator"):
        """A `zenoh.Config`: ``default_mode`` ("router" or "client") unless the flags say otherwise.

        ``--listen`` makes a router that listens there, ``--connect`` a client of that router;
        neither: a router on, or a client of, `DEFAULT_ENDPOINT` (a secure client: of the router
        that wrote the state folder). A ``--zenoh-config`` file is the starting point and only the
        flags given explicitly override it. Then, unless ``insecure``, a router enforces the
        security model and a client logs in as ``user`` (default ``default_user``); a client
        configuration file that already logs in (``.vrsim/viewer.json5``) is used as it is.
        """
        from vrsim.services.bus import security

        conf = self._base()
        if self.listen:
            mode, listen, connect = "router", list(self.listen), list(self.connect)
        elif self.connect:
            mode, listen, connect = "client", [], list(self.connect)
        elif self.config_file is not None:  # as the file says
            mode, listen, connect = json.loads(conf.get_json("mode")) or default_mode, None, None
        elif default_mode == "router":
            mode, listen, connect = "router", [self.default_endpoint], []
        else:
            mode, listen, connect = "client", [], self._default_connect(default_user)
        if listen is not None:
            conf.insert_json5("mode", json.dumps(mode))
            conf.insert_json5("listen/endpoints", json.dumps(listen))
            conf.insert_json5("connect/endpoints", json.dumps(connect))
        if mode == "router":
            _warn_plain_beyond_loopback(self._router_listen(conf))
        if self.insecure:
            return conf
        if mode == "router":
            state = security.prepare_state(self.state_dir, tls=self.tls)
            listen = self._router_listen(conf)
            security.apply_settings(conf, security.router_settings(state, self.keys, listen))
            security.write_client_configs(state, list(self.local_endpoints()))
            return conf
        if self.user is None and json.loads(conf.get_json("transport/auth/usrpwd/user")):
            return conf  # a complete client configuration that logs in by itself
        state = security.load_state(self.state_dir)
        return security.apply_settings(conf, security.credential_settings(state, self.user or default_user))

    def _default_connect(self, user: str) -> list[str]:
        """A client's router when no option names one: where the router that wrote the state folder
        listens (its ``<user>.json5``), else `DEFAULT_ENDPOINT`."""
        if self.insecure:
            return [DEFAULT_ENDPOINT]
        from vrsim.services.bus import security

        return security.recorded_endpoints(security.load_state(self.state_dir), user) or [DEFAULT_ENDPOINT]

    def _base(self):
        """The ``--zenoh-config`` file, or vrsim's defaults: no multicast scouting, no shared memory."""
        import zenoh

        if self.config_file is not None:
            try:
                return zenoh.Config.from_file(self.config_file)
            except (zenoh.ZError, OSError, ValueError) as exc:
                raise ServiceError(f"--zenoh-config {self.config_file}: {zenoh_reason(exc)}") from None
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("transport/shared_memory/enabled", "false")
        return conf

    @staticmethod
    def _router_listen(conf) -> list[str]:
        endpoints = json.loads(conf.get_json("listen/endpoints"))
        if isinstance(endpoints, dict):  # zenoh's per-mode form {"router": [...], "peer": [...]}
            endpoints = endpoints.get("router", [])
        return list(endpoints)

    def describe(self, default_mode: str) -> str:
        if self.listen:
            where = f"router on {', '.join(self.listen)}"
        elif self.connect:
            where = f"client of {', '.join(self.connect)}"
        elif self.config_file:
            where = f"as configured in {self.config_file}"
        else:
            role = "router on" if default_mode == "router" else "client of"
            where = f"{role} {self.default_endpoint if default_mode == 'router' else 'the router'}"
        return where + (", INSECURE: an open bus" if self.insecure else "")

    def local_endpoints(self) -> tuple[str, ...]:
        """Where a process on this machine reaches this process's router (its listen endpoints, with
        the any-address replaced by loopback)."""
        connect = self.connect or self.listen or self._config_listen() or (self.default_endpoint,)
        return tuple(ep.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for ep in connect)

    def child_args(self, user: str) -> list[str]:
        """Command-line options that make a child service a client of this process's router, logged in
        as ``user`` (with the same ``--zenoh-config`` as the parent)."""
        args = [a for ep in self.local_endpoints() for a in ("--connect", ep)]
        args += ["--prefix", self.prefix, "--machine", self.machine]
        if self.config_file is not None:
            args += ["--zenoh-config", os.path.abspath(self.config_file)]
        if self.insecure:
            return args + ["--insecure"]
        return args + ["--state-dir", os.path.abspath(self.state_dir), "--user", user]

    def _config_listen(self) -> tuple[str, ...]:
        """The router's listen endpoints in the ``--zenoh-config`` file, if it has one."""
        if self.config_file is None:
            return ()
        return tuple(self._router_listen(self._base()))


PLAIN_PROTOCOLS = ("tcp", "udp", "ws")  # what crosses a network unencrypted (tls and quic do not)


def _plain_beyond_loopback(endpoints) -> list[str]:
    """The endpoints of ``endpoints`` a router would listen on in plain text beyond this machine: a
    plain protocol on any address but a loopback one (``0.0.0.0``, ``[::]``, a LAN address or a host
    name other than ``localhost``)."""
    import ipaddress

    found = []
    for endpoint in endpoints:
        protocol, _, address = endpoint.partition("/")
        if protocol not in PLAIN_PROTOCOLS:
            continue
        host = re.split(r"[?#]", address, maxsplit=1)[0].rsplit(":", 1)[0].strip("[]")
        try:
            loopback = ipaddress.ip_address(host).is_loopback
        except ValueError:
            loopback = host == "localhost"
        if not loopback:
            found.append(endpoint)
    return found


def _warn_plain_beyond_loopback(endpoints) -> None:
    """One line on stderr when a router would listen in plain text beyond this machine: logins and
    every message (poses, maps, scenarios) would cross the network readable and forgeable."""
    plain = _plain_beyond_loopback(endpoints)
    if plain:
        print(f"vrsim serve: warning: the router listens on {', '.join(plain)} in plain text beyond this "
              "machine: passwords and every message cross the network unencrypted (use --tls, or a "
              "loopback address)", file=sys.stderr, flush=True)


def add_arguments(parser, user_help: str = "log in as this user (default: the service's own)") -> None:
    """The Zenoh options every serving or querying command takes."""
    parser.add_argument("--listen", metavar="ENDPOINT", action="append", default=[],
                        help=f"be a router listening here (repeatable; e.g. {DEFAULT_ENDPOINT})")
    parser.add_argument("--connect", metavar="ENDPOINT", action="append", default=[],
                        help=f"connect to a router here (repeatable; default {DEFAULT_ENDPOINT}, or where "
                             "the state folder says)")
    parser.add_argument("--zenoh-config", metavar="FILE", default=None,
                        help="zenoh JSON5 configuration file (routers, other hosts, ...)")
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"key prefix (default {DEFAULT_PREFIX})")
    parser.add_argument("--machine", default=DEFAULT_MACHINE,
                        help=f"machine name in the keys (default {DEFAULT_MACHINE})")
    parser.add_argument("--state-dir", metavar="DIR", default=DEFAULT_STATE_DIR,
                        help=f"private folder of the bus's credentials (default {DEFAULT_STATE_DIR})")
    parser.add_argument("--user", default=None, help=user_help)
    parser.add_argument("--insecure", action="store_true",
                        help="no authentication or access control: an open bus (experiments only)")
    parser.add_argument("--tls", action="store_true",
                        help="a router: TLS on its links, with a private CA in the state folder")


def options_from_args(args) -> ZenohOptions:
    return ZenohOptions(listen=tuple(args.listen), connect=tuple(args.connect),
                        config_file=args.zenoh_config, prefix=args.prefix, machine=args.machine,
                        state_dir=args.state_dir, user=args.user, insecure=args.insecure, tls=args.tls)


def open_session(options: ZenohOptions, default_mode: str = "client", default_user: str = "operator"):
    """`zenoh.open` with a message that says where it tried to connect."""
    import zenoh

    conf = options.config(default_mode, default_user)
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        where = options.describe(default_mode)
        login = "" if options.insecure else f" as user {options.user or default_user}"
        raise ServiceError(f"cannot open a zenoh session ({where}{login}): {zenoh_reason(exc)}; "
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
    def monitor_end(self) -> str:
        return self._m("monitor/end")

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
    unit: str | None = None  # map file: the unit of its rates when the file does not state it
    db: str | None = None  # monitor: its SQLite file (None: runs/monitor/<prefix>-<machine>.sqlite)
    web_listen: str | None = None  # web: HOST:PORT of the page (None: 127.0.0.1:8448)
    operator: ZenohOptions | None = None  # web: the session that may start and stop runs (None: viewer)
    # controller: folders whose Python files a scenario's [controller] kind = "python" may run (a
    # scenario comes over the bus, so by default no user code runs; absolute paths)
    user_code_dirs: tuple[str, ...] = ()
    data_root: str = "."  # files named by scenarios received over the bus must lie under this folder
