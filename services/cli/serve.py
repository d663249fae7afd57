"""`vrsim serve SERVICE [SCENARIO]`: run one Zenoh service, or `all` of them as separate processes.

``all`` is the router (listening on 127.0.0.1:7448 unless ``--listen`` says otherwise) and starts
map, vehicle, controller, monitor and scenario as child processes connected to it; Ctrl-C or SIGTERM
stops them all. A single service is a client of a router (``--connect``, default 127.0.0.1:7448), or
a router itself with ``--listen``. See docs/api.md for the keys.

Secure by default (docs/api.md, "Security"): the router generates credentials into the private
``--state-dir`` and enforces who may do what, every child logs in as its own user, files named by
scenarios from the bus must lie under ``--data-root`` and error messages quote no file content.
``--insecure`` opens the bus, with a warning.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import signal
import subprocess
import sys
import threading
import time

from vrsim.common import ServiceError, files
from vrsim.services.bus.client import alive_services, request_json
from vrsim.services.bus.config import (
    SERVICES,
    Keys,
    ServiceConfig,
    ZenohOptions,
    add_arguments,
    open_session,
    options_from_args,
)
from vrsim.services.bus.serving import PARENT_ENV, declare_alive, wait_for_signal
from vrsim.services.cli.aog import add_serve_arguments, serve_aog_rc
from vrsim.services.cli.options import add_input_cap, apply_input_cap

HELP = ("run the Zenoh services: map, vehicle, controller, monitor, scenario, router, web, or all; "
        "or aog-rc, the AgOpenGPS Rate Controller's modules and AgIO over UDP (docs/aog_rc.md)")
CHOICES = (*SERVICES, "router", "web", "all", "aog-rc")
READY_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0


def configure(parser) -> None:
    parser.add_argument("service", choices=CHOICES, metavar="SERVICE",
                        help=f"one of {', '.join(CHOICES)}")
    parser.add_argument("scenario", nargs="?", default=None,
                        help="scenario file or built-in name: `all` starts a run of it once everything is "
                             "up; `map` serves its prescription (default: the built-in default's)")
    add_arguments(parser)
    parser.add_argument("--map", metavar="FILE", default=None,
                        help="map service: serve this map file instead of a scenario's prescription")
    parser.add_argument("--rate-field", default=None, help="map file: attribute holding the rate")
    parser.add_argument("--cell-size", type=float, default=None, metavar="M", help="map file: cell size, m")
    parser.add_argument("--crs", default=None, help="map file: its CRS when the file does not say")
    parser.add_argument("--unit", default=None, help="map file: unit of its rates when the file does not "
                        "state it (kg/ha, lb/ac, L/ha, gal/ac, seeds/ac, ...)")
    parser.add_argument("--db", metavar="FILE", default=None,
                        help="monitor: SQLite database (default runs/monitor/<prefix>-<machine>.sqlite)")
    parser.add_argument("--allow-user-code", metavar="PATH", action="append", default=[],
                        help="controller: run user-defined controllers (kind = \"python\") from this file, "
                             "or from the .py files directly in this folder as they are when the service "
                             "starts (repeatable; default none; `all SCENARIO` allows the folder of that "
                             "scenario's controller file)")
    parser.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                        help="all: clock of the run it starts (default lockstep)")
    parser.add_argument("--speed", type=float, default=1.0, help="all: real-time speed factor (default 1)")
    parser.add_argument("--ticks-per-message", type=int, default=None, metavar="N",
                        help="all: lockstep ticks per message (default 50)")
    parser.add_argument("--web", action="store_true",
                        help="all: also start the web service (the live page, with start and stop)")
    parser.add_argument("--web-listen", metavar="HOST:PORT", default=None,
                        help="all --web: where the page listens (default 127.0.0.1:8448; beyond loopback "
                             "over TLS, with --tls); `serve web` takes it as --listen HOST:PORT. The page "
                             "asks for a login: its URL with a token is printed at start")
    parser.add_argument("--operator", action="store_true",
                        help="web: allow starting and stopping runs from the page, through a session "
                             "logged in as `operator` from the state folder (default: a viewer)")
    parser.add_argument("--data-root", metavar="DIR", default=".",
                        help="files named by scenarios received over the bus must lie under DIR "
                             "(default: the folder serve runs in)")
    add_input_cap(parser)
    add_serve_arguments(parser)


INSECURE_WARNING = ("vrsim serve {name}: WARNING: --insecure: no authentication and no access control; any "
                    "process that reaches {where} can read every stream, start and stop runs, load maps and "
                    "forge records")


def run(args) -> int:
    if args.service == "aog-rc":   # UDP, not the bus: its own options (services.cli.aog)
        return serve_aog_rc(args)
    config = _service_config(args)
    apply_input_cap(args)
    files.show_content(False)  # files are named by others over the bus: messages never quote them
    if config.zenoh.insecure and not os.environ.get(PARENT_ENV):  # serve all warns for its children
        where = ", ".join(config.zenoh.local_endpoints())
        print(INSECURE_WARNING.format(name=args.service, where=where), file=sys.stderr, flush=True)
    if args.scenario is not None and args.service not in ("all", "map"):
        raise ServiceError(f"serve {args.service}: takes no SCENARIO ({args.scenario!r}); scenario control "
                           "sends each service the run's scenario (give it to `vrsim serve all` or "
                           "scenario/start)")
    if args.service == "all":
        return _serve_all(args, config.zenoh)
    return importlib.import_module(f"vrsim.services.bus.{args.service}").main(config)


def _service_config(args) -> ServiceConfig:
    if not os.path.isdir(args.data_root):
        raise ServiceError(f"--data-root {args.data_root}: not a folder")
    web_listen = None
    if args.service == "web":  # its --listen is the page's HOST:PORT: it is a zenoh client only
        if len(args.listen) > 1:
            raise ServiceError("serve web: give --listen HOST:PORT once")
        web_listen, args.listen = (args.listen or [None])[0], []
    options = options_from_args(args)
    # web --operator: start and stop go through a second session, logged in with the operator's
    # credential from the state folder (the web user itself is a viewer).
    operator = dataclasses.replace(options, user="operator") if args.operator else None
    return ServiceConfig(zenoh=options, scenario=args.scenario, map_file=args.map,
                         rate_field=args.rate_field, cell_size_m=args.cell_size, crs=args.crs,
                         unit=args.unit, db=args.db,
                         web_listen=web_listen or args.web_listen,
                         user_code_dirs=tuple(os.path.abspath(d) for d in args.allow_user_code),
                         operator=operator, data_root=args.data_root)


def _child_argv(args, options: ZenohOptions, name: str, user_code_dirs: tuple[str, ...] = ()) -> list[str]:
    # -P: vrsim's own modules, not a `services` package in the folder the command runs in
    argv = [sys.executable, "-P", "-m", "vrsim.services.cli", "serve", name]
    if name == "map" and args.map is None and args.scenario is not None:
        argv.append(_abs_if_file(args.scenario))  # positionals first: argparse takes them in one go
    argv += options.child_args(name)
    argv += ["--data-root", os.path.abspath(args.data_root)]
    if args.max_input_mb is not None:
        argv += ["--max-input-mb", repr(args.max_input_mb)]
    if name == "map":
        if args.map is not None:
            argv += ["--map", os.path.abspath(args.map)]
            for flag, value in (("--rate-field", args.rate_field), ("--cell-size", args.cell_size),
                                ("--crs", args.crs), ("--unit", args.unit)):
                if value is not None:
                    argv += [flag, str(value)]
    if name == "monitor" and args.db is not None:
        argv += ["--db", os.path.abspath(args.db)]
    if name == "web":
        argv += ["--operator"] + (["--listen", args.web_listen] if args.web_listen else [])
    if name == "controller":
        for folder in user_code_dirs:
            argv += ["--allow-user-code", folder]
    return argv


def _abs_if_file(spec: str) -> str:
    return os.path.abspath(spec) if os.path.exists(spec) else spec


def _serve_all(args, options: ZenohOptions) -> int:
    """Be the router, start every service as a child process, stop them all on SIGINT/SIGTERM."""
    start_payload = start_selector = None
    if args.web:
        from vrsim.services.bus.web import DEFAULT_LISTEN, check_listen, parse_listen

        # Before anything starts: beyond loopback the page needs the bus's TLS certificates.
        check_listen(*parse_listen(args.web_listen or DEFAULT_LISTEN, "serve all: --web-listen"),
                     tls=options.tls, insecure=options.insecure)
    user_code_dirs = tuple(os.path.abspath(d) for d in args.allow_user_code)
    if args.scenario is not None:  # refuse a bad scenario or run option before starting anything
        from vrsim.services.bus import messages
        from vrsim.services.sim import scenario

        for flag, value, (lo, hi) in (("--speed", args.speed, messages.SPEED_RANGE),
                                      ("--ticks-per-message", args.ticks_per_message,
                                       messages.TICKS_PER_MESSAGE_RANGE)):
            if value is not None and not lo <= value <= hi:
                raise ServiceError(f"{flag} {value:g}: must be within [{lo:g}, {hi:g}]")
        sc = scenario.load(args.scenario)
        start_payload, start_selector = _start_request(options.keys, sc, args)
        if sc.controller.file is not None:   # the user named this scenario, and so its controller
            user_code_dirs += (os.path.dirname(sc.controller.file),)
    # SIGTERM before the serving loop takes over must still stop the children (via `finally`).
    signal.signal(signal.SIGTERM, _interrupt)
    stop = threading.Event()
    procs: dict[str, subprocess.Popen] = {}
    env = dict(os.environ, **{PARENT_ENV: str(os.getpid())})
    with open_session(options, "router") as session:
        token = declare_alive(session, options.keys, "router")
        try:
            for name in SERVICES + (("web",) if args.web else ()):
                procs[name] = subprocess.Popen(_child_argv(args, options, name, user_code_dirs), env=env)
            _wait_ready(session, options.keys, procs)
            if start_payload is not None:
                reply = request_json(session, start_selector, start_payload, timeout_s=120.0,
                                        what="vrsim serve all: starting the scenario")
                print(f"vrsim serve all: started run {reply['run_id']}", file=sys.stderr, flush=True)
            login = "" if options.insecure else \
                f", log in with {os.path.join(options.state_dir, '<user>.json5')} (operator, viewer)"
            print(f"vrsim serve all: ready ({options.describe('router')}, prefix {options.prefix}, "
                  f"machine {options.machine}{login}); Ctrl-C stops", file=sys.stderr, flush=True)
            reported: set[str] = set()

            def watch() -> bool:
                for name, proc in procs.items():
                    if proc.poll() is not None and name not in reported:
                        reported.add(name)
                        print(f"vrsim serve all: the {name} service exited with code {proc.returncode}",
                              file=sys.stderr, flush=True)
                return False

            wait_for_signal(stop, also=watch)
        finally:
            _stop_children(procs)
            token.undeclare()
    print("vrsim serve all: stopped", file=sys.stderr, flush=True)
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _start_request(keys: Keys, sc, args) -> tuple[bytes, str]:
    """The scenario/start query for a loaded scenario (its text, source and folder)."""
    from vrsim.services.sim.scenario import scenario_file

    with open(scenario_file(sc), "rb") as fh:
        text = fh.read()
    params = {"source": sc.source, "base_dir": sc.base_dir, "clock": args.clock, "speed": args.speed}
    if args.ticks_per_message is not None:
        params["ticks_per_message"] = args.ticks_per_message
    return text, keys.scenario("start") + "?" + ";".join(f"{k}={v}" for k, v in params.items())


def _wait_ready(session, keys: Keys, procs: dict) -> None:
    deadline = time.monotonic() + READY_TIMEOUT_S
    while True:
        alive = set(alive_services(session, keys, timeout_s=1.0))
        missing = [n for n in procs if n not in alive]
        if not missing:
            return
        dead = [f"{n} (exit code {p.returncode})" for n, p in procs.items() if p.poll() is not None]
        if dead:
            raise ServiceError(f"serve all: service(s) failed to start: {', '.join(dead)}")
        if time.monotonic() > deadline:
            raise ServiceError(f"serve all: waited {READY_TIMEOUT_S:g} s for the services to declare their "
                               f"liveliness tokens ({keys.alive('*')}); still missing: {', '.join(missing)}")
        time.sleep(0.1)


def _stop_children(procs: dict) -> None:
    for proc in procs.values():
        if proc.poll() is None:
            proc.terminate()
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for name, proc in procs.items():
        try:
            proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            print(f"vrsim serve all: the {name} service did not stop within {STOP_TIMEOUT_S:g} s; killing it",
                  file=sys.stderr, flush=True)
            proc.kill()
            proc.wait()
