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

A scenario arrives over the bus, so a ``kind = "python"`` controller runs only from a file the
operator named when the service started (``--allow-user-code PATH``: that file, or the ``.py`` files
directly in that folder as they were listed at start; `_allowed_files`), and only when the file binds
the scenario's class at its top level (read as text first, `check_defines_class`): anything else is
refused naming the file before any of it runs. ``control/load?check=true`` makes only those checks
(scenario control asks it before it accepts a run).
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading

import numpy as np

from vrsim.common import ServiceError, VrsimError
from vrsim.common.section_masks import section_masks
from vrsim.controller.kinds.python import check_defines_class
from vrsim.services.bus import messages
from vrsim.services.bus.config import ServiceConfig
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.serving import Params, run_service, serve
from vrsim.services.outputs.encode import dumps
from vrsim.services.sim.landing import applied_rate_kg_ha


class _ControllerService:
    """The handlers of the controller service; publishes through ``publish(key, payload)``."""

    def __init__(self, keys, publish, data: DataRoot, user_code: tuple[str, ...] = ()):
        self.keys = keys
        self.publish = publish
        self.data = data
        self.user_code = tuple(user_code)  # as the operator gave them, for messages
        self.allowed = _allowed_files(self.user_code)  # {real path: the entry that allowed it}
        self.lock = threading.Lock()
        self.run_id = ""
        self.core = None
        self.next_tick = 0
        self.period_s = math.nan

    def load(self, params: Params, payload: bytes | None) -> bytes:
        params.only("check")
        check = params.text("check", "false")
        if check not in ("true", "false"):
            raise ServiceError(f"{params.key}: parameter check={check!r} must be true or false")
        start = messages.RunStart.from_json(payload)
        from vrsim.services.sim.core import ControlCore
        from vrsim.services.sim.world import build_world

        sc = self.data.scenario(start.scenario_text, start.source, start.base_dir)
        sc = self._check_user_code(params.key, sc)
        if check == "true":
            return dumps({"loaded": False, "checked": True, "run_id": start.run_id})
        world = build_world(sc)  # section control reads the planned path ahead
        core = ControlCore(world.grid, sc, world.field.polygon, world.path)
        with self.lock:
            self.run_id, self.core, self.next_tick = start.run_id, core, 0
            self.period_s = sc.timing.control_period_s
        return dumps({"loaded": True, "run_id": start.run_id})

    def _check_user_code(self, key: str, sc):
        """``sc`` with its user controller file (kind ``python``) resolved to the allowed file it is, or
        a `ServiceError` naming the file: not one the operator named at start, or one without the
        scenario's class at its top level. Nothing of the file runs here (it would run as this
        service)."""
        cfg = sc.controller
        if cfg.file is None:
            return sc
        real = os.path.realpath(cfg.file)
        if real not in self.allowed:
            allowed = ", ".join(self.user_code) or "none"
            raise ServiceError(f"{key}: [controller] file {cfg.file}: user code runs only from the files "
                               "this controller service was started with (--allow-user-code FILE, or the "
                               f".py files directly in a folder when it started; allowed: {allowed})")
        try:
            check_defines_class(real, cfg.class_name)
        except VrsimError as exc:
            raise ServiceError(f"{key}: [controller] {exc}") from None
        # The file checked, not whatever the path names later (a link changed meanwhile).
        return dataclasses.replace(sc, controller=dataclasses.replace(cfg, file=real))

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


def _allowed_files(entries: tuple[str, ...]) -> dict[str, str]:
    """{real path: entry} of the Python files ``--allow-user-code`` names: a file itself, or each
    ``.py`` regular file directly in a folder (not in its subfolders), listed once, now. A file added
    later, or a link changed to point elsewhere, is not among them until the service restarts."""
    allowed: dict[str, str] = {}
    for entry in entries:
        real = os.path.realpath(entry)
        if os.path.isdir(real):
            with os.scandir(real) as listing:
                found = [os.path.realpath(e.path) for e in listing if e.name.endswith(".py") and e.is_file()]
        elif os.path.isfile(real):
            found = [real]
        else:
            raise ServiceError(f"--allow-user-code {entry}: no such file or folder")
        allowed.update((path, entry) for path in found)
    return allowed


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
