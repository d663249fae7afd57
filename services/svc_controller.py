"""The controller service: poses in, PID + hydraulic plant, shaft state and rate samples out
(``vrsim serve controller``).

``<prefix>/<machine>/control/step`` takes a JSON array of `messages.Pose` (the ticks since the last
step, in order), runs `services.run.ControlCore.tick` on each measured position (the same core as
``vrsim run``), publishes the results on ``<prefix>/<machine>/shaft`` and ``.../rate`` and replies
with a `messages.StepAck`. The reply is what keeps a lockstep run in step: the vehicle sends the next
ticks only once the controller has processed these. ``.../control/load`` (from scenario control)
builds a fresh core for a new run.
"""

from __future__ import annotations

import math
import threading

from common import ServiceError
from services import messages
from services.zenoh_common import Params, ZenohOptions, dumps, run_service, serve


class ControllerService:
    """The handlers of the controller service; publishes through ``publish(key, payload)``."""

    def __init__(self, keys, publish):
        self.keys = keys
        self.publish = publish
        self.lock = threading.Lock()
        self.run_id = ""
        self.core = None
        self.next_tick = 0
        self.width_m = self.period_s = math.nan

    def load(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        start = messages.RunStart.from_json(payload)
        from services import scenario
        from services.run import ControlCore
        from services.svc_map import scenario_grid

        sc = scenario.parse(start.scenario_text, start.source, start.base_dir)
        core = ControlCore(scenario_grid(sc), sc)
        with self.lock:
            self.run_id, self.core, self.next_tick = start.run_id, core, 0
            self.width_m, self.period_s = sc.implement.width_m, sc.timing.control_period_s
        return dumps({"loaded": True, "run_id": start.run_id})

    def step(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        poses = messages.decode_batch(messages.Pose, payload)
        with self.lock:
            if self.core is None:
                raise ServiceError(f"{params.key}: no run loaded (start one with scenario/start)")
            self._check_order(params.key, poses)
            shafts, rates = self._tick_all(poses)
            self.next_tick = poses[-1].tick + 1
        self.publish(self.keys.shaft, messages.encode_batch(shafts))
        self.publish(self.keys.rate, messages.encode_batch(rates))
        return messages.StepAck(self.run_id, len(poses), poses[-1].tick).to_json()

    def _check_order(self, key: str, poses) -> None:
        for i, pose in enumerate(poses):
            if pose.run_id != self.run_id:
                raise ServiceError(f"{key}: pose of run {pose.run_id!r}, but run {self.run_id!r} is loaded")
            if pose.tick != self.next_tick + i:
                raise ServiceError(f"{key}: pose tick {pose.tick} out of order, "
                                   f"expected {self.next_tick + i}")

    def _tick_all(self, poses):
        tick = self.core.tick
        area_per_m = self.width_m * 1e-4  # ha per metre travelled
        shafts, rates = [], []
        for p in poses:
            out = tick(p.measured_x_m, p.measured_y_m, p.heading_rad, p.speed_m_s, p.implement_on)
            travelled_m = p.speed_m_s * self.period_s
            # Same 1 cm floor as `services.run.land` below which a rate is meaningless.
            applied = out.metered_kg / (area_per_m * travelled_m) if travelled_m > 0.01 else math.nan
            shafts.append(messages.ShaftState(p.run_id, p.tick, p.time_s, out.target_shaft_rpm, out.shaft_rpm,
                                              out.shaft_rev, out.current_a))
            rates.append(messages.RateSample(p.run_id, p.tick, p.time_s, out.landing_x_m, out.landing_y_m,
                                             out.prescribed_kg_ha, applied, out.metered_kg, p.implement_on))
        return shafts, rates

    def handlers(self) -> dict:
        return {"step": self.step, "load": self.load}


def main(options: ZenohOptions, stop: threading.Event | None = None) -> None:
    """Serve the controller until SIGINT/SIGTERM (or ``stop``)."""
    import zenoh

    keys = options.keys

    def declare(session):
        # BLOCK: a slow subscriber (the monitor) slows the run down instead of losing records.
        pubs = {k: session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                for k in (keys.shaft, keys.rate)}
        svc = ControllerService(keys, lambda key, payload: pubs[key].put(payload))
        queryable = serve(session, keys.control_ns, svc.handlers(), f"{keys.prefix}/{keys.machine}/control/",
                          "controller")
        return [queryable, *pubs.values()]

    run_service("controller", options, declare, stop=stop)
