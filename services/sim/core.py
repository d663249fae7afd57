"""The control core: fix -> landing point -> rate -> target shaft speed -> PID + plant -> product.

The one pure core that both `vrsim run` (the whole track at once) and the Zenoh controller service
(each lockstep batch, carrying its state over) call, so both give the same numbers.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from common import ControllerError, ScenarioError
from controller import PlantParams, build_loop
from maps import Grid, RatePolicy
from services.sim.look_ahead import LookAheadTuner, initial_look_ahead_s, known_delay_s
from services.sim.scenario import Scenario, as_dict

RUN_CHUNK = 20000   # ticks of stage 1 and the loop at a time (bounded memory, progress reports)
TUNE_CHUNK = 400    # with the look-ahead tune: ticks looked up ahead (re-done after each tuner update)


def plant_for(scenario: Scenario) -> PlantParams:
    """The scenario's plant with the implement's transmission ratio and shaft-speed limit: the machine
    is described once, in ``[implement]``."""
    imp = scenario.implement
    return dataclasses.replace(scenario.plant, transmission_ratio=imp.transmission_ratio,
                               shaft_rpm_max=imp.shaft_rpm_max)


def config_as_run(scenario: Scenario) -> dict:
    """The scenario as plain data with the parameters as the run used them (the plant with the
    implement's transmission ratio and shaft-speed limit, `plant_for`): summary.json's
    ``scenario_config`` and the report's settings."""
    return dict(as_dict(scenario), plant=dataclasses.asdict(plant_for(scenario)))


class ControlCore:
    """Control ticks: fix -> landing point -> rate -> target rpm -> PID + plant -> product.

    Deterministic and free of I/O; `vrsim run` (the whole track in one `run_track`) and the
    controller service (`run_track` on each lockstep batch, the state carried over) run the same
    two stages:

    1. `targets`: where product metered now will land, the prescription there (with the map's
       policy off the map), and the target shaft speed. No feedback, so vectorized over ticks. The
       landing point is predicted by dead reckoning from the fix: product metered now lands
       `delivery_delay_s` later, when the implement has moved ``speed * delay`` along its heading;
       the look-ahead adds the loop's lag if asked to (`services.sim.look_ahead`).
    2. the closed loop (PID, valve, motor): `controller.ClosedLoop.run` over the targets, one
       control period per tick (sequential by nature: one lifted matrix product per period).
    """

    def __init__(self, grid: Grid, scenario: Scenario, field_polygon=None):
        self.grid = grid
        self.field_polygon = field_polygon  # sections whose centre would land outside it switch off
        self.implement = scenario.implement
        self.policy = RatePolicy(mode=scenario.map.policy,
                                 default_rate_kg_ha=scenario.map.default_rate_kg_ha)
        timing, cfg, plant = scenario.timing, scenario.controller, plant_for(scenario)
        try:
            self.loop = build_loop(plant, cfg, control_period_s=timing.control_period_s,
                                   plant_step_s=timing.plant_step_s, n=1)
            look_ahead_s = initial_look_ahead_s(scenario, plant)
        except ControllerError as exc:   # a user's class that does not load, a bad valve calibration
            raise ScenarioError(f"{scenario.source}: [controller] {exc}") from None
        self.period_s = timing.control_period_s
        self.tuner = None if cfg.look_ahead_tune == 0 else LookAheadTuner(
            look_ahead_s, known_delay_s(scenario), cfg.look_ahead_tune, self.period_s)
        self._look_ahead_s = look_ahead_s
        self.last_rate_kg_ha = float("nan")

    @property
    def look_ahead_s(self) -> float:
        """How far ahead in time the rate is looked up now [s] (`services.sim.look_ahead`)."""
        return self._look_ahead_s if self.tuner is None else self.tuner.look_ahead_s

    def state(self) -> dict:
        """What the core carries from one batch of ticks to the next, as plain data (numpy arrays, NaN
        where no rate was commanded yet): the loop's state (plant, sensor delay line, controller), the
        rate policy's last rate, and the look-ahead tuner's state (None without the tune)."""
        return {"loop": self.loop.state, "last_rate_kg_ha": self.last_rate_kg_ha,
                "tuner": None if self.tuner is None else self.tuner.state()}

    def set_state(self, state: dict) -> None:
        """Continue from `state` (from `state`, also after JSON: lists for arrays, null for NaN)."""
        self.loop.set_state(state["loop"])
        last = state["last_rate_kg_ha"]
        self.last_rate_kg_ha = float("nan") if last is None else float(last)
        if self.tuner is not None:
            self.tuner.set_state(state["tuner"])

    def targets(self, x_m, y_m, heading_rad, speed_m_s, implement_on) -> dict[str, np.ndarray]:
        """Stage 1 over arrays of ticks (shape (n,)); advances the policy's memory."""
        lead_m = np.asarray(speed_m_s) * self.look_ahead_s
        lx = x_m + lead_m * np.cos(heading_rad)
        ly = y_m + lead_m * np.sin(heading_rad)
        found = self.grid.lookup(lx, ly)
        rate = self.policy.apply(found.rate_kg_ha, found.inside, self.last_rate_kg_ha)
        if rate.size:
            self.last_rate_kg_ha = float(rate[-1])
        width_on, offset = self.sections(lx, ly, heading_rad, implement_on)
        # Within the meter's speed range while applying; a zero rate or all sections off stop the shaft.
        wanted = self.implement.clip_shaft_rpm(self.implement.target_shaft_rpm(rate, speed_m_s, width_on))
        target = np.where(width_on > 0, wanted, 0.0)
        return {"landing_x_m": lx, "landing_y_m": ly, "prescribed_kg_ha": rate, "target_shaft_rpm": target,
                "width_on_m": width_on, "offset_m": offset}

    def sections(self, x_m, y_m, heading_rad, implement_on):
        """Working width of the sections that are on (m) and its centre's offset to the left (m).

        Section control as terminals do it: with the implement on, a section applies when its centre
        lands inside the field. The sections that are on are taken as one strip (they are contiguous
        on convex edges; on a notch this spreads a little product over the gap).
        """
        imp = self.implement
        on = np.asarray(implement_on, bool)
        if self.field_polygon is None:
            return np.where(on, imp.width_m, 0.0), np.zeros(on.shape)
        sec = imp.sections_on(self.field_polygon, x_m, y_m, heading_rad, on)
        count = sec.sum(axis=1)
        offsets = np.where(sec, imp.section_offsets_m, 0.0).sum(axis=1)
        return count * imp.section_width_m, np.divide(offsets, count, out=np.zeros(count.shape),
                                                      where=count > 0)

    def run_track(self, x_m, y_m, heading_rad, speed_m_s, implement_on,
                  progress=None) -> dict[str, np.ndarray]:
        """Both stages over a whole measured track; arrays of shape (n,) keyed as `CONTROL_KEYS`.

        The track goes through in chunks: stage 1 on a chunk, then the loop over it. With the
        look-ahead tune on, a chunk ends where the tuner moves the look-ahead, and the ticks after it
        are looked up again with the new one, so any split into batches gives the same numbers.
        """
        n = len(x_m)
        track = (x_m, y_m, heading_rad, speed_m_s, implement_on)
        chunk = RUN_CHUNK if self.tuner is None else TUNE_CHUNK
        parts, start = [], 0
        while not parts or start < n:   # once at least, so that an empty track gives empty arrays
            part = slice(start, min(n, start + chunk))
            rec = self.targets(*(np.asarray(a)[part] for a in track))
            if self.tuner is not None:
                args = (rec["prescribed_kg_ha"], rec["target_shaft_rpm"], rec["width_on_m"],
                        np.asarray(implement_on, bool)[part])
                keep = self.tuner.plan(*args)
                if keep is not None:     # the look-ahead moves there: look the rest up again
                    rec = {k: v[:keep] for k, v in rec.items()}
                    args = tuple(a[:keep] for a in args)
                    self.last_rate_kg_ha = float(rec["prescribed_kg_ha"][-1])
            out = self.loop.run(rec["target_shaft_rpm"])
            rec.update(shaft_rpm=out.shaft_rpm[:, 0], shaft_rev=out.shaft_rev[:, 0],
                       current_a=out.current_a[:, 0])
            if self.tuner is not None and len(rec["shaft_rev"]):
                self.tuner.observe(*args, rec["shaft_rev"] * 60.0 / self.period_s)
            parts.append(rec)
            start += len(rec["shaft_rev"])
            if progress is not None:
                progress(start, n)
        rec = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        rec["metered_kg"] = self._metered_kg(rec["shaft_rev"], rec["width_on_m"] > 0)
        return {key: rec[key] for key in CONTROL_KEYS}

    def _metered_kg(self, shaft_rev, applying) -> np.ndarray:
        # Sections off close the gate: what the shaft turns then stays in the hopper. An underdamped
        # motor can swing briefly backwards when it brakes hard; a roller turning back meters nothing
        # (it does not lift product off the ground), so only forward revolutions count.
        forward = np.maximum(shaft_rev, 0.0)
        return np.where(np.asarray(applying, bool), self.implement.mass_kg(forward), 0.0)


CONTROL_KEYS = ("landing_x_m", "landing_y_m", "prescribed_kg_ha", "target_shaft_rpm", "shaft_rpm",
                "shaft_rev", "current_a", "metered_kg", "width_on_m", "offset_m")
