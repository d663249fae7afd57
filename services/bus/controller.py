"""The controller service: poses in, rate controller + hydraulic plant, shaft state and rate samples
out (``vrsim serve controller``).

``<prefix>/<machine>/control/step`` takes a JSON array of `messages.Pose` (the ticks since the last
step, in order), runs `services.sim.core.ControlCore.run_track` on their measured positions (the core
``vrsim run`` runs over the whole track, here continued batch after batch: the PID and plant, the
map policy's memory and section control's coverage map, commands and gates carry over, so the
numbers are those of one run over the whole track), publishes the results on
``<prefix>/<machine>/shaft`` and ``.../rate`` and replies with a `messages.StepAck`. The reply is
what keeps a lockstep run in step: the vehicle is never more than one batch ahead of the replies.
``.../control/load`` (from scenario control) builds a fresh core for a new run: any controller kind,
its state (loop, look-ahead tuner, rate policy) carried from batch to batch by the core.
``.../control/state`` replies with that state as JSON (`ControlCore.state`), to save or inspect it.

A scenario arrives over the bus, so a ``kind = "python"`` controller runs only from a file inside a
folder the service was started with (``--allow-user-code DIR``); anything else is refused.
"""

from __future__ import annotations

import math
import os
import threading

import numpy as np

from common import ServiceError
from common.section_masks import section_masks
from services.bus import messages
from services.bus.config import ServiceConfig
from services.bus.dataroot import DataRoot
from services.bus.serving import Params, run_service, serve
from services.outputs.encode import dumps
from services.sim.landing import applied_rate_kg_ha


class _ControllerService:
    """The handlers of the controller service; publishes through ``publish(key, payload)``."""

    def __init__(self, keys, publish, data: DataRoot, user_code_dirs: tuple[str, ...] = ()):
        self.keys = keys
        self.publish = publish
        self.data = data
        self.user_code_dirs = tuple(os.path.realpath(d) for d in user_code_dirs)
        self.lock = threading.Lock()
        self.run_id = ""
        self.core = None
        self.next_tick = 0
        self.period_s = math.nan

    def load(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        start = messages.RunStart.from_json(payload)
        from services.sim.core import ControlCore
        from services.sim.world import build_world

        sc = self.data.scenario(start.scenario_text, start.source, start.base_dir)
        self._check_user_code(params.key, sc.controller.file)
        world = build_world(sc)  # section control reads the planned path ahead
        core = ControlCore(world.grid, sc, world.field.polygon, world.path)
        with self.lock:
            self.run_id, self.core, self.next_tick = start.run_id, core, 0
            self.period_s = sc.timing.control_period_s
        return dumps({"loaded": True, "run_id": start.run_id})

    def _check_user_code(self, key: str, file: str | None) -> None:
        """Refuse a user's controller file outside the allowed folders (it would run as this service)."""
        if file is None:
            return
        real = os.path.realpath(file)
        if not any(os.path.commonpath([real, d]) == d for d in self.user_code_dirs):
            allowed = ", ".join(self.user_code_dirs) or "none"
            raise ServiceError(f"{key}: [controller] file {file}: user code runs only from the folders this "
                               f"controller service allows (--allow-user-code DIR; allowed: {allowed})")

    def state(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        with self.lock:
            if self.core is None:
                raise ServiceError(f"{params.key}: no run loaded (start one with scenario/start)")
            return dumps({"run_id": self.run_id, "next_tick": self.next_tick, "core": self.core.state()})

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
        """`ControlCore.run_track` over this batch: the track's next ticks, so the loop's and the
        policy's state carry over from the previous batch exactly as within one `vrsim run`."""
        cols = ("measured_x_m", "measured_y_m", "heading_rad", "measured_speed_m_s", "s_m")
        mx, my, heading, speed, s_m = (np.array([getattr(p, c) for p in poses]) for c in cols)
        on = np.array([p.implement_on for p in poses])
        rec = self.core.run_track(mx, my, heading, speed, on, s_m)
        # The tick's strip as the controller sees it: measured speed x period (where the product
        # really lands, `vrsim run` and the monitor's report work out from the true path).
        applied = applied_rate_kg_ha(rec["metered_kg"], rec["width_on_m"], speed * self.period_s).tolist()
        masks = section_masks(rec.pop("sections_on"))
        del rec["sections_commanded"]  # not published: the gates are what lands
        out = {k: v.tolist() for k, v in rec.items()}
        steps = out.get("side_steps_on", [None] * len(poses))  # a spinner's steps on, where it steps
        shafts, rates = [], []
        for i, p in enumerate(poses):
            shafts.append(messages.ShaftState(p.run_id, p.tick, p.time_s, out["target_shaft_rpm"][i],
                                              out["shaft_rpm"][i], out["shaft_rev"][i], out["current_a"][i],
                                              out["drive_target_rpm"][i]))
            rates.append(messages.RateSample(p.run_id, p.tick, p.time_s, out["landing_x_m"][i],
                                             out["landing_y_m"][i], out["prescribed_kg_ha"][i], applied[i],
                                             out["metered_kg"][i], out["width_on_m"][i], masks[i],
                                             p.implement_on, out["drive_rate_kg_ha"][i], out["drive_kg"][i],
                                             steps[i]))
        return shafts, rates

    def handlers(self) -> dict:
        return {"step": self.step, "load": self.load, "state": self.state}


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Serve the controller until SIGINT/SIGTERM (or ``stop``)."""
    import zenoh

    keys = config.zenoh.keys

    def declare(session):
        # BLOCK: a slow subscriber (the monitor) slows the run down instead of losing records.
        pubs = {k: session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                for k in (keys.shaft, keys.rate)}
        svc = _ControllerService(keys, lambda key, payload: pubs[key].put(payload), DataRoot.of(config),
                                config.user_code_dirs)
        queryable = serve(session, keys.control_ns, svc.handlers(), f"{keys.prefix}/{keys.machine}/control/",
                          "controller")
        return [queryable, *pubs.values()]

    run_service("controller", config.zenoh, declare, stop=stop)
    return 0
