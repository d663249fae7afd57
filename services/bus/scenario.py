"""Scenario control: start, watch and stop a run across the services (``vrsim serve scenario``).

``<prefix>/scenario/start`` (body: a scenario file's TOML text, or empty for the built-in default)
parses and builds the scenario exactly as ``vrsim run`` does, so a bad one is refused with the same
message the CLI prints; then it loads the run into the map, controller and monitor services and
starts the vehicle. ``<prefix>/scenario/status`` says how far the run is, what the monitor has
stored, and which services are alive (liveliness tokens, so a killed service shows within
milliseconds); ``<prefix>/scenario/stop`` stops the vehicle. ``<prefix>/<anything>`` else at the top
level gets an error reply naming the keys that exist.
"""

from __future__ import annotations

import os
import re
import threading
import time

from common import ServiceError
from services.bus import client, messages
from services.bus.config import SERVICES, Keys, ServiceConfig
from services.bus.serving import Params, run_service, serve
from services.outputs.encode import dumps

LOAD_TIMEOUT_S = 120.0  # building a large map from a file can take a while
STATUS_TIMEOUT_S = 1.0  # status must answer within 2 s even when a service hangs
DEFAULT_TICKS_PER_MESSAGE = 50


def new_run_id(name: str, counter: int) -> str:
    """``<name>-<UTC time>-<pid>-<counter>``; characters that would break a selector parameter
    (``;`` ``#`` ``?`` ``&`` spaces ...) in the scenario's name become ``_``."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "run"
    return f"{safe}-{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}-{os.getpid()}-{counter}"


class ScenarioService:
    """Handlers of scenario control; ``session`` reaches the other services."""

    def __init__(self, session, keys: Keys):
        self.session, self.keys = session, keys
        self.lock = threading.Lock()  # one start or stop at a time
        self.counter = 0

    def start(self, params: Params, payload: bytes | None) -> bytes:
        params.only("source", "base_dir", "clock", "speed", "ticks_per_message")
        from services.sim import scenario
        from services.sim.world import build_world

        clock = params.text("clock", "lockstep")
        if clock not in messages.CLOCKS:
            raise ServiceError(f"{params.key}: parameter clock={clock!r} must be one of "
                               f"{', '.join(messages.CLOCKS)}")
        speed = params.number("speed", *messages.SPEED_RANGE, default=1.0)
        per_message = params.integer("ticks_per_message", *messages.TICKS_PER_MESSAGE_RANGE,
                                     default=DEFAULT_TICKS_PER_MESSAGE)
        text, source, base_dir = self._scenario_text(params, payload)
        sc = scenario.parse(text, source, base_dir)
        build_world(sc)  # refuses what `vrsim run` refuses (a missing map file, a map off the field...)
        with self.lock:
            # Check first, so that no service loads a run that cannot start.
            alive = client.alive_services(self.session, self.keys, timeout_s=STATUS_TIMEOUT_S)
            missing = [s for s in SERVICES if s != "scenario" and s not in alive]
            if missing:
                raise ServiceError(f"{params.key}: cannot start, service(s) not alive: {', '.join(missing)} "
                                   f"(liveliness {self.keys.alive('*')})")
            state = self._vehicle_status()
            if state is not None and state["state"] in ("starting", "running"):
                raise ServiceError(f"{params.key}: run {state['run_id']} is {state['state']}; "
                                   f"stop it first ({self.keys.scenario('stop')})")
            self.counter += 1
            run_id = new_run_id(sc.name, self.counter)
            start = messages.RunStart(run_id, text, source, base_dir, clock, speed, per_message)
            body = start.to_json()
            for key, name in ((self.keys.map_load, "map"), (self.keys.control_load, "controller"),
                              (self.keys.monitor_load, "monitor"), (self.keys.vehicle("start"), "vehicle")):
                client.request(self.session, key, body, LOAD_TIMEOUT_S,
                               what=f"{params.key}: the {name} service")
        return dumps({"run_id": run_id, "state": "running", "scenario": sc.name, "clock": clock})

    def _scenario_text(self, params: Params, payload: bytes | None) -> tuple[str, str, str]:
        from services.sim import scenario

        if not payload:  # the built-in default, refused as `vrsim run` would refuse it
            sc = scenario.load(None)
            with open(scenario.scenario_file(sc), encoding="utf-8") as fh:
                return fh.read(), sc.source, sc.base_dir
        try:
            text = payload.decode("utf-8")
        except UnicodeDecodeError:
            raise ServiceError(f"{params.key}: the body is not UTF-8 text (send a scenario TOML file)") \
                from None
        return text, params.text("source", "<scenario>"), params.text("base_dir", os.getcwd())

    def _vehicle_status(self) -> dict | None:
        try:
            return client.request_json(self.session, self.keys.vehicle("status"), timeout_s=STATUS_TIMEOUT_S)
        except ServiceError:
            return None

    def status(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        alive = client.alive_services(self.session, self.keys, timeout_s=STATUS_TIMEOUT_S)
        vehicle = self._vehicle_status() if "vehicle" in alive else None
        monitor = None
        if "monitor" in alive and vehicle is not None and vehicle["run_id"]:
            try:
                selector = f"{self.keys.monitor_status}?run_id={vehicle['run_id']}"
                monitor = client.request_json(self.session, selector, timeout_s=STATUS_TIMEOUT_S)
            except ServiceError:
                monitor = None
        silent = ("the vehicle service is not alive" if "vehicle" not in alive
                  else f"the vehicle service did not answer within {STATUS_TIMEOUT_S:g} s")
        out = {
            "state": vehicle["state"] if vehicle else "unknown",
            "run_id": vehicle["run_id"] if vehicle else "",
            "scenario": vehicle["scenario"] if vehicle else "",
            "clock": vehicle["clock"] if vehicle else "",
            "ticks": vehicle["ticks"] if vehicle else 0,
            "sim_time_s": vehicle["sim_time_s"] if vehicle else 0.0,
            "wall_s": vehicle["wall_s"] if vehicle else 0.0,
            "drive_s": vehicle["drive_s"] if vehicle else 0.0,
            "monitor_ticks": monitor["ticks"] if monitor else None,
            "live_mae_kg_ha": monitor["live_mae_kg_ha"] if monitor else None,
            "error": vehicle["error"] if vehicle else silent,
            "alive": alive,
            "missing": [s for s in SERVICES if s not in alive],
        }
        return dumps(out)

    def stop(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        with self.lock:
            return client.request(self.session, self.keys.vehicle("stop"), timeout_s=10.0,
                              what=f"{params.key}: the vehicle service")

    def handlers(self) -> dict:
        return {"start": self.start, "status": self.status, "stop": self.stop}


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Serve scenario control until SIGINT/SIGTERM (or ``stop``)."""
    keys = config.zenoh.keys
    hint = (f"the vrsim keys are {keys.map_info}, {keys.map_rate}, {keys.report}, {keys.pose}, {keys.shaft}, "
            f"{keys.rate}, {keys.scenario('start')}, {keys.scenario('status')}, {keys.scenario('stop')}; "
            "see docs/api.md")

    def declare(session):
        svc = ScenarioService(session, keys)
        return [serve(session, keys.scenario_ns, svc.handlers(), f"{keys.prefix}/scenario/", "scenario"),
                # <prefix>/<one chunk> is no vrsim key: answer so, rather than leave the caller in silence
                serve(session, keys.top_ns, {}, f"{keys.prefix}/", "scenario", hint=hint)]

    run_service("scenario", config.zenoh, declare, stop=stop)
    return 0
