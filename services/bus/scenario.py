"""Scenario control: start, watch and stop a run across the services (``vrsim serve scenario``).

``<prefix>/scenario/start`` (body: a scenario file's TOML text, or empty for the built-in default)
parses and builds the scenario exactly as ``vrsim run`` does, so a bad one is refused with the same
message the CLI prints (files it names must lie under the data root, `services.bus.dataroot`); it
checks that the services are alive, that no run is going, and (for a user's controller class) that
the controller service will run its file; then it replies that the run is accepted, with its id and
the key to follow it by (``status``). Only then is the run loaded into the map, controller and
monitor services and handed to the vehicle, in a thread of its own (`_Launch`): a failure there shows
in ``status``. Parsing and building run in a thread of their own too (the building at most
`BUILD_TIMEOUT_S`), so ``status`` and ``stop`` answer meanwhile; a client waits
`services.bus.config.ACCEPT_TIMEOUT_S` for the reply.
``<prefix>/scenario/status`` says how far the run is, what the monitor has stored, and which
services are alive (liveliness tokens, so a killed service shows within milliseconds);
``<prefix>/scenario/stop`` stops the vehicle. ``<prefix>/<anything>`` else at the top level gets an
error reply naming the keys that exist. Scenario control owns the runs it starts, so it also tells the
monitor how each ended (`_RunEnds`: finished, stopped, failed or interrupted, and the last tick).
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field

from vrsim.common import ServiceError, VrsimError
from vrsim.services.bus import client, messages
from vrsim.services.bus.config import SERVICES, Keys, ServiceConfig
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.serving import Later, Params, run_service, serve, within
from vrsim.services.outputs.encode import dumps

LOAD_TIMEOUT_S = 120.0  # building a large map from a file can take a while
BUILD_TIMEOUT_S = 60.0  # building the world of a scenario (the caps make a real one take seconds)
STATUS_TIMEOUT_S = 1.0  # status must answer within 2 s even when a service hangs
CHECK_TIMEOUT_S = 20.0  # the controller service's check of a user's controller file (no building)
DEFAULT_TICKS_PER_MESSAGE = 50


def _new_run_id(name: str, counter: int) -> str:
    """``<name>-<UTC time>-<pid>-<counter>``; characters that would break a selector parameter
    (``;`` ``#`` ``?`` ``&`` spaces ...) in the scenario's name become ``_``."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "run"
    return f"{safe}-{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}-{os.getpid()}-{counter}"


_WATCH_S = 0.5  # how often scenario control looks at a live run's vehicle
_END_RETRY_S = 600.0  # an end the monitor did not take (it was down) is offered again this long
_END_STATES = ("finished", "stopped", "failed")  # the vehicle's states that end a run


class _RunEnds:
    """Announces each run's end to the monitor (``monitor/end``, `messages.RunEnd`): scenario control
    starts runs, so it watches the one it started until the vehicle says it ended (finished, stopped,
    failed) or the vehicle service is gone or restarted (interrupted), then tells the monitor; an end
    the monitor does not take (down at the time) is offered again for `_END_RETRY_S`.

    `observe` takes every vehicle status scenario control reads (its ``status`` too, so a client that
    saw ``finished`` there gets a report that knows it); a thread looks every `_WATCH_S` meanwhile.
    """

    def __init__(self, session, keys: Keys, vehicle_status):
        self.session, self.keys, self.vehicle_status = session, keys, vehicle_status
        self.lock = threading.Lock()
        self.sending = threading.Lock()  # one announcer at a time, so an end goes out once
        self.live: messages.RunEnd | None = None  # the run started, as far as it was seen to get
        self.pending: list[tuple[float, messages.RunEnd]] = []  # (when it ended, end) not yet taken
        self.closed = threading.Event()
        self.thread = threading.Thread(target=self._watch, name="vrsim-run-ends", daemon=True)
        self.thread.start()

    def started(self, run_id: str) -> None:
        with self.lock:
            self.live = messages.RunEnd(run_id, "interrupted", 0, 0.0, "")

    def ended(self, end: messages.RunEnd) -> None:
        """Announce the end of a run that never reached the vehicle (its launch failed or was stopped
        after the monitor had loaded it)."""
        with self.lock:
            self.pending.append((time.monotonic(), end))
        self.flush()

    def observe(self, status: dict | None, alive: list[str] | None = None) -> None:
        """Decide from a vehicle status (None: no answer) and the services alive (None: not asked)
        whether the live run ended; announce it if so."""
        with self.lock:
            live = self.live
            if live is None:
                return
            if status is not None and status["run_id"] == live.run_id:
                if status["state"] not in _END_STATES:
                    self.live = dataclasses.replace(live, ticks=status["ticks"],
                                                    sim_time_s=status["sim_time_s"])
                    return
                end = messages.RunEnd(live.run_id, status["state"], status["ticks"], status["sim_time_s"],
                                      status["error"])
            elif status is not None:  # a vehicle that knows nothing of the run: it restarted
                end = dataclasses.replace(live, error="the vehicle service restarted during the run")
            elif alive and "vehicle" not in alive:  # the bus answers, the vehicle is gone
                end = dataclasses.replace(live, error="the vehicle service went away during the run")
            else:  # no answer at all (the router is down, say): not known yet
                return
            self.live = None
            self.pending.append((time.monotonic(), end))
        self.flush()

    def flush(self) -> None:
        """Offer the monitor every end it has not taken yet."""
        with self.sending:
            with self.lock:
                pending, self.pending = self.pending, []
            kept = []
            for when, end in pending:
                try:
                    client.request(self.session, self.keys.monitor_end, end.to_json(), STATUS_TIMEOUT_S,
                                   what=f"{self.keys.monitor_end}: the monitor")
                except ServiceError as exc:
                    if "no reply" in str(exc) and time.monotonic() - when < _END_RETRY_S:
                        kept.append((when, end))  # the monitor is down: offered again later
                    else:
                        print(f"vrsim serve scenario: the end of run {end.run_id} ({end.reason}) was not "
                              f"stored: {exc}", file=sys.stderr, flush=True)
            with self.lock:
                self.pending = kept + self.pending

    def _watch(self) -> None:
        while not self.closed.wait(_WATCH_S):
            try:
                if self.live is not None:
                    status = self.vehicle_status()
                    alive = None if status is not None else client.alive_services(self.session, self.keys,
                                                                                  STATUS_TIMEOUT_S)
                    self.observe(status, alive)
                if self.pending:
                    self.flush()
            except Exception:  # noqa: BLE001 - a bug (or a closing session): the watch goes on
                traceback.print_exc(file=sys.stderr)

    def close(self) -> None:
        self.closed.set()
        self.thread.join(timeout=5.0)


_MAX_END_ERROR_CHARS = 2000  # messages.RunEnd's cap on its error


@dataclass
class _Launch:
    """A run scenario control accepted: after the reply it is loaded into the map, controller and
    monitor services and handed to the vehicle (`_ScenarioService._launch`). Until the vehicle drives
    it, ``status`` shows it from here: ``starting`` while it loads (its ``run_id`` still empty there,
    since a client that saw it would ask the monitor for a run not yet loaded; ``accepted_run_id``
    names it), ``failed`` or ``stopped`` if it never reached the vehicle."""

    start: messages.RunStart
    scenario: str
    t0: float = field(default_factory=time.monotonic)
    state: str = "starting"  # "starting", "driving" (the vehicle has it), "failed" or "stopped"
    error: str = ""
    announced: bool = False  # the monitor has loaded it: its end is owed to the monitor

    def status(self) -> dict:
        """The fields of `messages.RunStatus` for this launch."""
        return {"state": self.state, "run_id": "" if self.state == "starting" else self.start.run_id,
                "scenario": self.scenario, "clock": self.start.clock, "ticks": 0, "sim_time_s": 0.0,
                "wall_s": time.monotonic() - self.t0, "drive_s": 0.0, "error": self.error,
                "speed": self.start.speed}

    def end(self) -> messages.RunEnd:
        return messages.RunEnd(self.start.run_id, self.state, 0, 0.0, self.error[:_MAX_END_ERROR_CHARS])


class _ScenarioService:
    """Handlers of scenario control; ``session`` reaches the other services."""

    def __init__(self, session, keys: Keys, data: DataRoot):
        self.session, self.keys, self.data = session, keys, data
        self.lock = threading.Lock()  # one start or stop at a time
        self.building = threading.Lock()  # one world being built at a time (held until it is done)
        self.counter = 0
        self.launch: _Launch | None = None  # the run accepted last
        self.ends = _RunEnds(session, keys, self._vehicle_status)

    def start(self, params: Params, payload: bytes | None) -> Later:
        params.only("source", "base_dir", "clock", "speed", "ticks_per_message")
        clock = params.text("clock", "lockstep")
        if clock not in messages.CLOCKS:
            raise ServiceError(f"{params.key}: parameter clock={clock!r} must be one of "
                               f"{', '.join(messages.CLOCKS)}")
        speed = params.number("speed", *messages.SPEED_RANGE, default=1.0)
        per_message = params.integer("ticks_per_message", *messages.TICKS_PER_MESSAGE_RANGE,
                                     default=DEFAULT_TICKS_PER_MESSAGE)
        # Parsing reads what the scenario names (a spinner's catch-tray profile): in the reply's thread,
        # so that status and stop answer meanwhile.
        return Later(lambda: self._accept(params, payload, (clock, speed, per_message)))

    def _accept(self, params: Params, payload: bytes | None, run: tuple) -> bytes:
        """Check the scenario and the services as `vrsim run` and the run would, accept the run, and
        start loading it (`_launch`); the reply says it was accepted and where to follow it."""
        key = params.key
        text, source, base_dir = self._scenario_text(params, payload)
        sc = self.data.scenario(text, source, base_dir)
        start = messages.RunStart("", text, source, base_dir, *run)
        self._build(key, sc)
        self._check_alive(key)
        if sc.controller.file is not None:  # refused now, not after the reply, and none of it runs
            client.request(self.session, f"{self.keys.control_load}?check=true", start.to_json(),
                           CHECK_TIMEOUT_S, what=f"{key}: the controller service")
        with self.lock:
            self._check_free(key)
            self.counter += 1
            start = dataclasses.replace(start, run_id=_new_run_id(sc.name, self.counter))
            launch = self.launch = _Launch(start, sc.name)
        threading.Thread(target=self._launch, args=(key, launch), name="vrsim-launch", daemon=True).start()
        return dumps({"run_id": start.run_id, "accepted": True, "state": "starting", "scenario": sc.name,
                      "clock": start.clock, "status": self.keys.scenario("status")})

    def _build(self, key: str, sc) -> None:
        """`build_world(sc)` in its own thread, at most `BUILD_TIMEOUT_S`: it refuses what `vrsim run`
        refuses (a missing map file, a map off the field...)."""
        from vrsim.services.sim.world import build_world

        if not self.building.acquire(blocking=False):
            raise ServiceError(f"{key}: still building the world of an earlier start; try again later")

        def build():
            try:
                build_world(sc)
            finally:
                self.building.release()

        within(BUILD_TIMEOUT_S, build, f"{key}: building the world of {sc.source}")

    def _check_alive(self, key: str) -> None:
        alive = client.alive_services(self.session, self.keys, timeout_s=STATUS_TIMEOUT_S)
        missing = [s for s in SERVICES if s != "scenario" and s not in alive]
        if missing:
            raise ServiceError(f"{key}: cannot start, service(s) not alive: {', '.join(missing)} "
                               f"(liveliness {self.keys.alive('*')})")

    def _check_free(self, key: str) -> None:
        """Refuse while a run is loading or driving (``self.lock`` held)."""
        launch = self.launch
        if launch is not None and launch.state == "starting":
            raise ServiceError(f"{key}: run {launch.start.run_id} is starting; "
                               f"stop it first ({self.keys.scenario('stop')})")
        state = self._vehicle_status()
        self.ends.observe(state)  # the run before this one ended, if it had not been seen to
        if state is not None and state["state"] in ("starting", "running"):
            raise ServiceError(f"{key}: run {state['run_id']} is {state['state']}; "
                               f"stop it first ({self.keys.scenario('stop')})")

    def _launch(self, key: str, launch: _Launch) -> None:
        """Load the accepted run into the map, controller and monitor and hand it to the vehicle; a
        failure (or a stop) shows in status, and the monitor, if it had loaded the run, is told."""
        body = launch.start.to_json()
        try:
            for load, name in ((self.keys.map_load, "map"), (self.keys.control_load, "controller"),
                               (self.keys.monitor_load, "monitor")):
                if launch.state != "starting":  # stopped meanwhile
                    break
                client.request(self.session, load, body, LOAD_TIMEOUT_S, what=f"{key}: the {name} service")
                launch.announced = launch.announced or name == "monitor"
            # A stop comes either before the vehicle has the run (and cancels it) or after (and stops it).
            with self.lock:
                if launch.state == "starting":
                    self._hand_to_vehicle(key, launch, body)
                    launch.state = "driving"
                    self.ends.started(launch.start.run_id)
        except VrsimError as exc:
            self._launch_failed(launch, str(exc))
        except Exception as exc:  # noqa: BLE001 - a bug: the run fails visibly, the service lives on
            traceback.print_exc(file=sys.stderr)
            self._launch_failed(launch, f"internal error: {type(exc).__name__}: {exc}")
        if launch.state in ("failed", "stopped") and launch.announced:
            self.ends.ended(launch.end())

    def _hand_to_vehicle(self, key: str, launch: _Launch, body: bytes) -> None:
        try:
            client.request(self.session, self.keys.vehicle("start"), body, LOAD_TIMEOUT_S,
                           what=f"{key}: the vehicle service")
        except ServiceError:
            status = self._vehicle_status()  # a reply lost or late: the vehicle may drive it all the same
            if status is None or status["run_id"] != launch.start.run_id:
                raise

    def _launch_failed(self, launch: _Launch, error: str) -> None:
        with self.lock:
            if launch.state == "starting":
                launch.state, launch.error = "failed", error

    def _scenario_text(self, params: Params, payload: bytes | None) -> tuple[str, str, str]:
        from vrsim.services.sim import scenario

        if not payload:  # the built-in default, refused as `vrsim run` would refuse it
            sc = scenario.load(None)
            with open(scenario.scenario_file(sc), encoding="utf-8") as fh:
                return fh.read(), sc.source, sc.base_dir
        try:
            text = payload.decode("utf-8")
        except UnicodeDecodeError:
            raise ServiceError(f"{params.key}: the body is not UTF-8 text (send a scenario TOML file)") \
                from None
        return text, params.text("source", "<scenario>"), params.text("base_dir", self.data.root)

    def _vehicle_status(self) -> dict | None:
        try:
            return client.request_json(self.session, self.keys.vehicle("status"), timeout_s=STATUS_TIMEOUT_S)
        except ServiceError:
            return None

    def status(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        alive = client.alive_services(self.session, self.keys, timeout_s=STATUS_TIMEOUT_S)
        vehicle = self._vehicle_status() if "vehicle" in alive else None
        self.ends.observe(vehicle, alive)
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
            "speed": vehicle["speed"] if vehicle else None,
            "monitor_ticks": monitor["ticks"] if monitor else None,
            "live_mae_kg_ha": monitor["live_mae_kg_ha"] if monitor else None,
            "error": vehicle["error"] if vehicle else silent,
            "alive": alive,
            "missing": [s for s in SERVICES if s not in alive],
        }
        launch = self.launch
        if launch is not None and launch.state != "driving" and (vehicle is None
                                                                 or vehicle["run_id"] != launch.start.run_id):
            # it has not reached the vehicle (yet): the monitor's figures would be an older run's
            out.update(launch.status(), monitor_ticks=None, live_mae_kg_ha=None)
        out.update(_realtime_factors(out["clock"], out.pop("speed"), out["sim_time_s"], out["drive_s"]))
        out["accepted_run_id"] = launch.start.run_id if launch is not None else ""
        return dumps(out)

    def stop(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        with self.lock:
            launch = self.launch
            if launch is not None and launch.state == "starting":  # still loading: it never drives
                launch.state = "stopped"
                return messages.RunStatus(**launch.status()).to_json()
            reply = client.request(self.session, self.keys.vehicle("stop"), timeout_s=10.0,
                                   what=f"{params.key}: the vehicle service")
        self.ends.observe(messages.RunStatus.from_json(reply).to_dict())
        return reply

    def handlers(self) -> dict:
        return {"start": self.start, "status": self.status, "stop": self.stop}


def _realtime_factors(clock: str, speed_asked, sim_time_s: float, drive_s: float) -> dict:
    """``realtime_factor_asked``: the speed a realtime run was asked to keep (None for lockstep, which
    runs as fast as the controller answers); ``realtime_factor``: what the run kept, simulated seconds
    per wall second since its first tick (None before it)."""
    asked = float(speed_asked) if clock == "realtime" and isinstance(speed_asked, (int, float)) else None
    kept = sim_time_s / drive_s if drive_s > 0 else None
    return {"realtime_factor_asked": asked, "realtime_factor": kept}


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Serve scenario control until SIGINT/SIGTERM (or ``stop``)."""
    keys = config.zenoh.keys
    hint = (f"the vrsim keys are {keys.map_info}, {keys.map_rate}, {keys.report}, {keys.pose}, {keys.shaft}, "
            f"{keys.rate}, {keys.scenario('start')}, {keys.scenario('status')}, {keys.scenario('stop')}; "
            "see docs/api.md")

    def declare(session):
        svc = _ScenarioService(session, keys, DataRoot.of(config))
        return [svc.ends,
                serve(session, keys.scenario_ns, svc.handlers(), f"{keys.prefix}/scenario/", "scenario"),
                # <prefix>/<one chunk> is no vrsim key: answer so, rather than leave the caller in silence
                serve(session, keys.top_ns, {}, f"{keys.prefix}/", "scenario", hint=hint)]

    run_service("scenario", config.zenoh, declare, stop=stop)
    return 0
