"""`vrsim aog ACTION`: the AgOpenGPS Rate Controller app's side, for users without the Windows app (and
`vrsim serve aog-rc`, whose serving part lives here too: `serve_aog_rc`).

* ``vrsim aog target UPM``: send a product's PID settings, its relays (all on) and a target in units per
  minute every second for ``--duration`` s, and print what the module reports (one line a second);
* ``vrsim aog watch``: print what the modules report (``--count`` lines), sending nothing;
* ``vrsim aog app RATE``: be the app in a field run: read AgIO's speed and sections, send the product's
  target (RATE units per hectare over ``--section-width`` m sections) and relays 5 times a second until
  AgIO goes quiet.

See docs/aog_rc.md.
"""

from __future__ import annotations

import os
import sys
import time

from vrsim.common import ServiceError, VrsimError

HELP = "be the AgOpenGPS Rate Controller app towards rate modules over UDP (e.g. `vrsim serve aog-rc`)"
ACTIONS = ("target", "watch", "app")
DEFAULT_LISTEN = "127.0.0.1:28888"
QUIET_S = 4.0     # `app`: AgIO silent this long ends it


def configure(parser) -> None:
    parser.add_argument("action", choices=ACTIONS, help="target: send a target and print the reports; watch: "
                        "print the reports; app: be the app in a field run")
    parser.add_argument("value", nargs="?", type=float, default=None,
                        help="target: units per minute; app: units per hectare")
    parser.add_argument("--modules-at", metavar="HOST:PORT", default=DEFAULT_LISTEN,
                        help=f"where the modules listen (default {DEFAULT_LISTEN})")
    parser.add_argument("--listen", metavar="HOST:PORT", default="127.0.0.1:29999",
                        help="where to receive the modules' reports (default 127.0.0.1:29999)")
    parser.add_argument("--agio-listen", metavar="HOST:PORT", default="127.0.0.1:17777",
                        help="app: where to receive AgIO's PGNs (default 127.0.0.1:17777)")
    parser.add_argument("--module", type=int, default=0, help="module ID 0-7 (default 0)")
    parser.add_argument("--sensor", type=int, default=0, help="sensor ID 0-15 (default 0)")
    parser.add_argument("--meter-cal", type=float, default=10.0, metavar="PULSES",
                        help="flow meter calibration, pulses per unit (default 10)")
    parser.add_argument("--control", type=int, default=0, metavar="TYPE",
                        help="0 valve (default), 1 combo close, 2 motor, 4 fan, 5 combo close timed")
    parser.add_argument("--kp", type=int, default=45, help="Kp slider 0-100 (default 45)")
    parser.add_argument("--ki", type=int, default=70, help="Ki slider 0-100 (default 70)")
    parser.add_argument("--section-width", type=float, action="append", default=[], metavar="M",
                        help="app: a section's width, m (repeat per section)")
    parser.add_argument("--duration", type=float, default=10.0, metavar="S",
                        help="target: seconds (default 10)")
    parser.add_argument("--count", type=int, default=10, help="watch: lines to print (default 10)")
    parser.add_argument("--pid-log", action="store_true", help="ask the module for its PID samples (32402)")


def run(args) -> int:
    from vrsim.services.aog.app_client import AppClient

    _check(args)
    try:
        client = AppClient(_parse_host_port(args.modules_at, "--modules-at"),
                           _parse_host_port(args.listen, "--listen"),
                           _parse_host_port(args.agio_listen, "--agio-listen")
                           if args.action == "app" else None)
    except OSError as exc:
        raise ServiceError(f"cannot listen on {args.listen}: {exc.strerror}") from None
    with client:
        return {"target": _target, "watch": _watch, "app": _app}[args.action](args, client)


def _check(args) -> None:
    if not 0 <= args.module < 8:
        raise VrsimError(f"--module {args.module}: must be 0-7")
    if not 0 <= args.sensor < 16:
        raise VrsimError(f"--sensor {args.sensor}: must be 0-15")
    if args.action in ("target", "app") and (args.value is None or not 0 <= args.value < 16000):
        raise VrsimError(f"{args.action}: give a value in [0, 16000) ({args.value!r})")
    if args.action == "app" and not args.section_width:
        raise VrsimError("app: give the sections' widths (--section-width M, once per section)")
    if not 0 < args.meter_cal < 16000:
        raise VrsimError(f"--meter-cal {args.meter_cal:g}: must be in (0, 16000)")


def _line(msg: dict) -> str:
    return (f"module {msg['module']} sensor {msg['sensor']}: applied {msg['upm']:.3f} units/min, "
            f"pwm {msg['pwm']}, "
            f"{msg['hz']:.1f} Hz, quantity {msg['quantity']:.1f}, connected {msg['connected']}")


def _target(args, client) -> int:
    client.send_pid(args.module, args.sensor, kp=args.kp, ki=args.ki)
    end = time.monotonic() + args.duration
    while time.monotonic() < end:
        client.send_relays(args.module, 0xFFFF)
        client.send_rate(args.module, args.sensor, args.value, args.meter_cal, control_type=args.control,
                         pid_logging=args.pid_log)
        client.poll(1.0)
        msg = client.rates.get((args.module, args.sensor))
        print(f"target {args.value:.3f}; " + (_line(msg) if msg else "no report yet"), flush=True)
    return 0


def _watch(args, client) -> int:
    shown = 0
    while shown < args.count:
        for msg in client.poll(1.0):
            if msg["pgn"] == 32400:
                print(_line(msg), flush=True)
                shown += 1
    return 0


def _app(args, client) -> int:
    from vrsim.services.aog.app_client import AppProduct

    product = AppProduct(args.module, args.sensor, args.value, tuple(args.section_width), args.meter_cal,
                         args.control)
    client.send_pid(args.module, args.sensor, kp=args.kp, ki=args.ki)
    if not client.wait_for(lambda c: c.agio_packets > 0, 30.0):
        raise ServiceError(f"app: no AgIO packet on {args.agio_listen} within 30 s")
    last_agio, seen, last_print = time.monotonic(), client.agio_packets, 0.0
    while time.monotonic() - last_agio < QUIET_S:
        target = product.send(client, pid_logging=args.pid_log)
        client.poll(0.2)
        if client.agio_packets != seen:
            last_agio, seen = time.monotonic(), client.agio_packets
        if time.monotonic() - last_print >= 1.0:
            last_print = time.monotonic()
            msg = client.rates.get((args.module, args.sensor))
            print(f"speed {client.speed():.1f} km/h, width {product.working_width_m(client):.1f} m, target "
                  f"{target:.3f}; " + (_line(msg) if msg else "no report yet"), flush=True)
    return 0


def _parse_host_port(text: str, flag: str, default_port: int | None = None) -> tuple[str, int]:
    """``HOST:PORT`` (or ``HOST`` with `default_port`) as (host, port); a `VrsimError` naming `flag`."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, "" if default_port is None else str(default_port)
    try:
        number = int(port)
    except ValueError:
        raise VrsimError(f"{flag} {text}: give HOST:PORT") from None
    if not host or not 0 < number < 65536:
        raise VrsimError(f"{flag} {text}: give HOST:PORT with a port in 1-65535")
    return host, number


# -- vrsim serve aog-rc ------------------------------------------------------------------------------------

SPEED_RANGE = (0.1, 100.0)
MODULES_HELP = "MODULE:SENSORS,...: the modules emulated and their sensor counts (default 0:1)"


def add_serve_arguments(parser) -> None:
    """`vrsim serve aog-rc`'s own options (`services.cli.serve.configure` adds them to serve's)."""
    group = parser.add_argument_group("aog-rc (docs/aog_rc.md; --listen HOST:PORT is where the modules "
                                      "listen, default 127.0.0.1:28888; --machine FILE a machine file, "
                                      "machine_fit.toml from vrsim fit; --speed the real-time factor)")
    group.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                       help="aog-rc: override a scenario key, as for vrsim run (repeatable)")
    group.add_argument("--modules", default="0:1", help=f"aog-rc: {MODULES_HELP}")
    group.add_argument("--app", metavar="HOST:PORT", default="127.0.0.1:29999",
                       help="aog-rc: where the app receives the modules' reports (default 127.0.0.1:29999; "
                            "a subnet's broadcast, x.y.z.255:29999, reaches the app on another machine)")
    group.add_argument("--agio", metavar="HOST:PORT", default="127.0.0.1:17777",
                       help="aog-rc: where AgIO's PGNs go, the app's AgIO port (default 127.0.0.1:17777)")
    group.add_argument("--no-field", action="store_true",
                       help="aog-rc: the modules alone, no drive and no AgIO (until --duration or Ctrl-C)")
    group.add_argument("--duration", type=float, default=None, metavar="S",
                       help="aog-rc --no-field: stop after S simulated seconds")
    group.add_argument("--out", metavar="DIR", default=None,
                       help="aog-rc: output folder (default runs/aog-rc-<scenario>-<time>/); status.json "
                            "in it is rewritten every second")
    group.add_argument("--valve-travel-s", type=float, default=None, metavar="S",
                       help="aog-rc: a valve's full stroke at PWM 255 (default 3 s)")
    group.add_argument("--no-ack", action="store_true",
                       help="aog-rc: report only every 200 ms, as the firmware (default: a 32400 answers "
                            "each 32500 at once too)")


def _parse_modules(text: str) -> list[tuple[int, int]]:
    """``--modules`` as [(module ID, sensors)]."""
    out = []
    for part in text.split(","):
        mod, sep, count = part.strip().partition(":")
        try:
            module, sensors = int(mod), int(count) if sep else 1
        except ValueError:
            raise VrsimError(f"--modules {text}: {MODULES_HELP}") from None
        if not 0 <= module < 8 or not 1 <= sensors <= 16 or module in dict(out):
            raise VrsimError(f"--modules {text}: module IDs 0-7, once each, 1-16 sensors")
        out.append((module, sensors))
    return out


def serve_aog_rc(args) -> int:
    """`vrsim serve aog-rc [SCENARIO]`: see docs/aog_rc.md."""
    from vrsim.services.bus.config import DEFAULT_MACHINE
    from vrsim.services.cli.options import apply_input_cap, overrides_of
    from vrsim.services.cli.run import default_out_dir

    apply_input_cap(args)
    machine_file = args.machine if args.machine != DEFAULT_MACHINE else None
    if len(args.listen) > 1:
        raise VrsimError("serve aog-rc: give --listen HOST:PORT once")
    from vrsim.services.aog.service import Endpoints, beyond_loopback

    listen = args.listen[0] if args.listen else DEFAULT_LISTEN
    endpoints = Endpoints(_parse_host_port(listen, "--listen", 28888),
                          _parse_host_port(args.app, "--app", 29999),
                          _parse_host_port(args.agio, "--agio", 17777))
    if not SPEED_RANGE[0] <= args.speed <= SPEED_RANGE[1]:
        raise VrsimError(f"--speed {args.speed:g}: must be within [{SPEED_RANGE[0]:g}, {SPEED_RANGE[1]:g}]")
    if args.duration is not None and not 0 < args.duration < 1e7:
        raise VrsimError(f"--duration {args.duration:g}: must be a positive number of seconds")
    if args.valve_travel_s is not None and not 0.05 <= args.valve_travel_s <= 600:
        raise VrsimError(f"--valve-travel-s {args.valve_travel_s:g}: must be within [0.05, 600]")
    modules = _parse_modules(args.modules)
    if beyond_loopback(endpoints.listen[0]):
        host, port = endpoints.listen
        print(f"vrsim serve aog-rc: warning: the modules listen on {host}:{port} "
              "beyond this machine: UDP has no login, anyone who reaches it can set the rates and the relays "
              "(use a loopback address unless the app runs on another machine)", file=sys.stderr, flush=True)
    scenario_args = type("ScenarioArgs", (), {"machine": machine_file, "overrides": args.overrides})()
    from vrsim.services.sim.scenario import load

    sc = load(args.scenario, overrides_of(scenario_args))
    return _serve(args, sc, endpoints, modules, machine_file, default_out_dir(sc.name, "aog-rc"))


def _serve(args, sc, endpoints, modules, machine_file, default_out: str) -> int:
    from vrsim.services.aog.field import FieldRun
    from vrsim.services.aog.firmware import LOOP_MS, VALVE_TRAVEL_S, DrivePlant, RateModule
    from vrsim.services.aog.report import write_aog_files
    from vrsim.services.aog.service import AogService
    from vrsim.services.sim.core import machine_plant
    from vrsim.services.sim.machines import machine_for
    from vrsim.services.sim.world import build_world

    if abs(sc.timing.control_period_s * 1000.0 - LOOP_MS) > 1e-9:
        raise VrsimError(f"{sc.source}: [timing] control_period_s {sc.timing.control_period_s:g}: "
                         "serve aog-rc "
                         f"ticks with the modules' {LOOP_MS} ms loop; set it to {LOOP_MS / 1000:g}")
    field_run = None if args.no_field else FieldRun(sc)
    if field_run is not None:
        world, machine, plant = field_run.world, field_run.core.machine, field_run.plant
        units_per_rev = field_run.units_per_rev
    else:
        world = build_world(sc)
        machine = machine_for(world.scenario.implement, world.field.polygon)
        plant = machine_plant(world.scenario, world.grid, machine)
        units_per_rev = float(machine.configured_kg(1.0, world.scenario.product))
    travel = VALVE_TRAVEL_S if args.valve_travel_s is None else args.valve_travel_s
    step_s = world.scenario.timing.plant_step_s
    rate_modules = [RateModule(mod, [DrivePlant(plant, units_per_rev, step_s, travel) for _ in range(n)])
                    for mod, n in modules]
    out_dir = args.out or default_out
    os.makedirs(out_dir, exist_ok=True)
    service = AogService(rate_modules, endpoints, args.speed, field_run, args.duration,
                         os.path.join(out_dir, "status.json"), ack=not args.no_ack)
    try:
        service.run()
    except OSError as exc:
        raise ServiceError(f"serve aog-rc: cannot listen on {endpoints.listen[0]}:{endpoints.listen[1]}: "
                           f"{exc.strerror}") from None
    settings = {"scenario": sc.name, "machine_file": machine_file, "modules": modules, "speed": args.speed,
                "units": "kg (a sprayer's litres times the product's density)",
                "units_per_rev": units_per_rev,
                "valve_travel_s": travel, "listen": list(endpoints.listen), "app": list(endpoints.app),
                "agio": list(endpoints.agio), "field": field_run is not None}
    write_aog_files(service, out_dir, settings)
    c = service.counters.as_dict()
    print(f"vrsim serve aog-rc: stopped ({service.ended}) after {service.tick * LOOP_MS / 1000:.1f} s "
          "simulated; "
          f"received {c['received']}, accepted {sum(c['accepted'].values())}, dropped {c['dropped_total']} "
          f"({', '.join(f'{k} {v}' for k, v in c['dropped'].items() if v) or 'none'}); sent "
          f"{c['sent']['32400']} PGN 32400, {c['sent']['32402']} PGN 32402, {c['sent']['agio']} AgIO",
          file=sys.stderr, flush=True)
    if field_run is not None and field_run.done > 0:
        from vrsim.services.outputs.summary import text_summary
        from vrsim.services.outputs.write import outputs_line, write_outputs

        result = field_run.result()
        write_outputs(result, out_dir)
        print(text_summary(result.summary))
        print(outputs_line(out_dir, world.scenario.output.track_formats))
    print(f"  aog-rc files in {out_dir}/ (aog_rc.json, aog_rc.csv, aog_rc.png, status.json)")
    return 0
