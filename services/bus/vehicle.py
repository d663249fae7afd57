"""The vehicle service: drives the tractor in SUMO and publishes its pose (``vrsim serve vehicle``).

The only process that runs SUMO (libsumo holds one simulation per process). A run is started by
scenario control through ``<prefix>/<machine>/vehicle/start`` (body: `messages.RunStart`); a worker
thread then steps `vehicle.SumoDriver` one control period at a time, reads the sensors per tick
(`vehicle.Gnss.fix`, `vehicle.SpeedSensor.read`: the same numbers as the vectorized ``measure`` of
``vrsim run``), publishes ``<prefix>/<machine>/pose`` and sends the same poses to
``.../control/step`` (at most one batch ahead of the replies, see `_StepPipe`). Clocks: ``lockstep``
batches ``ticks_per_message`` ticks per message and runs as fast as the controller answers;
``realtime`` sends every tick when simulation time, divided by the speed factor, reaches the wall
clock.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback

from vrsim.common import ServiceError, VrsimError
from vrsim.services.bus import messages
from vrsim.services.bus.config import ServiceConfig
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.serving import Params, error_message, run_service, serve

STEP_TIMEOUT_S = 10.0  # a controller that does not answer a step within this fails the run


class _VehicleService:
    """Run state and handlers of the vehicle service; the drive loop runs in a worker thread."""

    def __init__(self, session, keys, publish_pose, data: DataRoot | None = None):
        self.session, self.keys, self.publish_pose = session, keys, publish_pose
        self.data = data
        self.lock = threading.Lock()
        self.status = messages.RunStatus("idle", "", "", "", 0, 0.0, 0.0, 0.0, "")
        self.stop_flag = threading.Event()
        self.worker: threading.Thread | None = None
        self.wall0 = time.monotonic()
        self.drive0: float | None = None  # when the first tick was driven

    # ------------------------------------------------------------------ handlers
    def start(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        start = messages.RunStart.from_json(payload)
        with self.lock:
            if self.status.state in ("starting", "running"):
                raise ServiceError(f"{params.key}: run {self.status.run_id} is {self.status.state}; "
                                   "stop it first")
            sc = self.data.scenario(start.scenario_text, start.source, start.base_dir)
            self.stop_flag.clear()
            self.wall0, self.drive0 = time.monotonic(), None
            self.status = messages.RunStatus("starting", start.run_id, sc.name, start.clock, 0, 0.0, 0.0, 0.0,
                                             "", start.speed)
            # The world is built in the worker, so that status and stop answer while it is built.
            self.worker = threading.Thread(target=self._run, args=(start, sc), name="vrsim-drive",
                                           daemon=True)
            self.worker.start()
            return self.status.to_json()

    def stop(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        self.stop_flag.set()
        worker = self.worker
        if worker is not None:
            worker.join(timeout=5.0)
        return self._status_json()

    def get_status(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        return self._status_json()

    def _status_json(self) -> bytes:
        with self.lock:
            st = self.status
            if st.state in ("starting", "running"):
                self._clock(st)
            return st.to_json()

    def handlers(self) -> dict:
        return {"start": self.start, "stop": self.stop, "status": self.get_status}

    def close(self) -> None:
        self.stop_flag.set()
        if self.worker is not None:
            self.worker.join(timeout=5.0)

    # ------------------------------------------------------------------ the drive loop
    def _set(self, **changes) -> None:
        with self.lock:
            for name, value in changes.items():
                setattr(self.status, name, value)
            self._clock(self.status)

    def _clock(self, st: messages.RunStatus) -> None:
        now = time.monotonic()
        st.wall_s = now - self.wall0
        st.drive_s = now - self.drive0 if self.drive0 is not None else 0.0

    def _run(self, start: messages.RunStart, sc) -> None:
        from vrsim.services.sim.world import build_world

        try:
            state = self._drive(start, build_world(sc))
            self._set(state=state)
        except VrsimError as exc:
            self._set(state="failed", error=str(exc))
        except Exception as exc:  # noqa: BLE001 - a bug: the run fails visibly, the service lives on
            traceback.print_exc(file=sys.stderr)
            self._set(state="failed", error=f"internal error: {type(exc).__name__}: {exc}")

    def _drive(self, start: messages.RunStart, world) -> str:
        from vrsim.services.sim.run import sensors
        from vrsim.services.sim.world import driving

        sc = world.scenario
        period = sc.timing.control_period_s
        realtime = start.clock == "realtime"
        per_message = 1 if realtime else start.ticks_per_message
        querier = self.session.declare_querier(self.keys.control_step, timeout=STEP_TIMEOUT_S)
        pipe = _StepPipe(querier, self.publish_pose, self.keys.control_step)
        try:
            with driving(sc, world.path) as driver:  # the time limit of `vrsim run`, enforced by the driver
                gnss, speed_sensor = sensors(sc)  # seeded as `vrsim run` seeds them
                wall0, batch, tick, state = time.monotonic(), [], 0, "finished"
                self.drive0 = wall0
                self._set(state="running")
                while not driver.finished:
                    if self.stop_flag.is_set():
                        state = "stopped"
                        break
                    p = driver.step()
                    mx, my = gnss.fix(p.time_s, p.x_m, p.y_m)
                    mv = speed_sensor.read(p.time_s, p.speed_m_s)
                    batch.append(messages.Pose(start.run_id, tick, p.time_s, p.x_m, p.y_m, mx, my,
                                               p.heading_rad, p.speed_m_s, mv, bool(p.implement_on), p.s_m))
                    tick += 1
                    if realtime:
                        delay = wall0 + p.time_s / start.speed - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    if len(batch) >= per_message:
                        pipe.send(batch)
                        self._set(ticks=tick, sim_time_s=p.time_s)
                        batch = []
                pipe.send(batch)
                pipe.wait()
                self._set(ticks=tick, sim_time_s=tick * period)
            return state
        finally:
            querier.undeclare()


class _StepPipe:
    """Sends pose batches to ``control/step``, never more than one batch ahead of the replies.

    The vehicle drives the next batch while the controller works on this one (nearly twice the
    ticks per second of waiting for each reply); `send` queries the new batch, then waits for the
    reply to the previous one, so at most two are ever unanswered. Replies
    are checked in order; a missing or error reply fails the run with the controller's message.
    """

    def __init__(self, querier, publish_pose, key: str):
        self.querier, self.publish_pose, self.key = querier, publish_pose, key
        self.pending = None  # (reply handler, first tick) of the batch in flight

    def send(self, batch: list) -> None:
        if not batch:
            return
        payload = messages.encode_batch(batch)
        self.publish_pose(payload)
        handler = self.querier.get(payload=payload)
        self.wait()
        self.pending = (handler, batch[0].tick)

    def wait(self) -> None:
        """Until the batch in flight has been answered."""
        if self.pending is None:
            return
        handler, tick = self.pending
        self.pending = None
        replies = list(handler)
        if any(reply.ok is not None for reply in replies):
            return
        if not replies:
            raise ServiceError(f"{self.key}: no controller answered at tick {tick} (controller not alive)")
        message = error_message(replies[0].err.payload.to_bytes())
        if message.lower().startswith("timeout"):
            message = f"no reply within {STEP_TIMEOUT_S:g} s"
        raise ServiceError(f"{self.key}: controller failed at tick {tick}: {message}")


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Serve the vehicle until SIGINT/SIGTERM (or ``stop``)."""
    import zenoh

    keys = config.zenoh.keys

    def declare(session):
        pub = session.declare_publisher(keys.pose, congestion_control=zenoh.CongestionControl.BLOCK)
        svc = _VehicleService(session, keys, pub.put, DataRoot.of(config))
        queryable = serve(session, keys.vehicle_ns, svc.handlers(), f"{keys.prefix}/{keys.machine}/vehicle/",
                          "vehicle")
        return [queryable, svc, pub]

    run_service("vehicle", config.zenoh, declare, stop=stop)
    return 0

