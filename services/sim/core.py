"""The control core: fix -> landing point -> rate -> target shaft speed -> PID + plant -> product.

The one pure core that both `vrsim run` (the whole track at once) and the Zenoh controller service
(each lockstep batch, carrying its state over) call, so both give the same numbers.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vrsim.common import ControllerError, ScenarioError
from vrsim.controller import PlantParams, build_loop
from vrsim.controller.context import ContextTrack
from vrsim.maps import Grid, RatePolicy
from vrsim.services.sim.look_ahead import LookAheadTuner, initial_look_ahead_s, known_delay_s
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.resolve import config_as_run, plant_for  # noqa: F401 - config_as_run: re-exported
from vrsim.services.sim.scenario import Scenario
from vrsim.services.sim.sections import STEPS_KEY, SectionStates, SectionSwitch
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle.product import metered_kg
from vrsim.vehicle.response import PassClock

OPENING_KEY = "opening_gain"   # stage 1's factor of a pass start's opening transient per tick (n,)
RUN_CHUNK = 20000   # ticks of stage 1 and the loop at a time (bounded memory, progress reports)
TUNE_CHUNK = 400    # with the look-ahead tune: ticks looked up ahead (re-done after each tuner update)


def machine_plant(scenario: Scenario, grid: Grid, machine=None) -> PlantParams:
    """The plant each metering drive's loop closes: the kind's (`Machine.loop_plant`), from `plant_for`'s,
    with the machine's dead time (``[response] dead_time_s``) inside the loop, on its sensor's delay.
    `machine`: the kind's run-time part when the caller has it (it binds the product to it)."""
    machine = machine_for(scenario.implement) if machine is None else machine
    plant = machine.loop_plant(plant_for(scenario), scenario, grid)
    dead_s = scenario.response.dead_time_s
    return plant if dead_s == 0 else dataclasses.replace(plant, sensor_delay_s=plant.sensor_delay_s + dead_s)


class ControlCore:
    """Control ticks: fix -> landing point -> rate -> sections -> target rpm -> PID + plant -> product.

    Deterministic and free of I/O; `vrsim run` (the whole track in one `run_track`) and the
    controller service (`run_track` on each lockstep batch, the state carried over) run the same
    stages:

    1. `targets`: where product metered now will land, the prescription there (with the map's
       policy off the map), which sections apply (`services.sim.sections.SectionSwitch`, stateful:
       coverage control remembers where product landed) and the target shaft speed for the width
       whose gates are open. No feedback, so vectorized over ticks. The landing point is predicted
       from the fix: product metered now lands `delivery_delay_s` later, where the sensed speed,
       acceleration and yaw rate take the implement (`services.sim.sections.motion`, the same
       prediction as the sections'); the look-ahead adds the loop's lag
       if asked to (`services.sim.look_ahead`). The sections decide on their own look-ahead (their
       latencies and the delivery delay), so they do not depend on the rate's look-ahead.
    2. the closed loop (PID, valve, motor; or any controller kind, `controller.build_loop`) over the
       targets, one control period per tick (sequential by nature: one lifted matrix product per period).
       A controller that takes the context gets the sensed ground speed, the prescription and the
       sections of each tick (`context_track`).

    Parameters
    ----------
    grid : maps.Grid
        The prescription in the field's metric CRS.
    scenario : Scenario
    field_polygon : shapely geometry
        The field boundary (section control switches sections off outside it).
    path : vehicle.CoveragePath, optional
        The planned path (coverage section control reads off it where the path works).
    """

    def __init__(self, grid: Grid, scenario: Scenario, field_polygon, path=None):
        self.grid = grid
        self.implement = scenario.implement
        self.policy = RatePolicy(mode=scenario.map.policy,
                                 default_rate_kg_ha=scenario.map.default_rate_kg_ha)
        self.machine = machine_for(self.implement, field_polygon)
        timing, cfg, plant = scenario.timing, scenario.controller, machine_plant(scenario, grid, self.machine)
        self.plant = plant
        try:   # a loop per metering drive, all advanced by one lifted matrix product per period
            self.loop = build_loop(plant, cfg, control_period_s=timing.control_period_s,
                                   plant_step_s=timing.plant_step_s, n=self.machine.drives)
            look_ahead_s = initial_look_ahead_s(scenario, plant)
        except ControllerError as exc:   # a user's class that does not load, a bad valve calibration
            raise ScenarioError(f"{scenario.source}: [controller] {exc}") from None
        self.period_s = timing.control_period_s
        self.tuner = None if cfg.look_ahead_tune == 0 else LookAheadTuner(
            look_ahead_s, known_delay_s(scenario), cfg.look_ahead_tune, self.period_s)
        self._look_ahead_s = look_ahead_s
        self.switch = SectionSwitch(self.implement, field_polygon, path, self.period_s, min(grid.cell_size),
                                    self.machine.side_steps)
        self.last_rate_kg_ha = np.full(self.machine.drives, np.nan)   # each drive's, for the policy
        self.product, self.seed = scenario.product, scenario.seed
        self.response = scenario.response
        self.passes = PassClock(self.response, self.period_s) if self.response.follows_passes else None
        # Forward revolutions so far, each drive's (or each column's, sweeps' variants): the product's
        # flow factors run on them (`vehicle.product.metered_kg`).
        self.meter_rev = np.zeros(self.machine.drives)

    @property
    def look_ahead_s(self) -> float:
        """How far ahead in time the rate is looked up now [s] (`services.sim.look_ahead`)."""
        return self._look_ahead_s if self.tuner is None else self.tuner.look_ahead_s

    def state(self) -> dict:
        """What the core carries from one batch of ticks to the next, as plain data (numpy arrays, NaN
        where no rate was commanded yet): the loop's state (plant, sensor delay line, controller), the
        rate policy's last rate, the look-ahead tuner's state (None without the tune) and the section
        switch's (`services.sim.sections.SectionSwitch.state`: with coverage control its coverage
        map, commands and gates), the shafts' positions and the pass clock's (`vehicle.response.PassClock`;
        None without a ``[response]`` that follows the passes). The last rate is a number for one
        metering drive, a list for several."""
        return {"loop": self.loop.state,
                "last_rate_kg_ha": _number_or_list(self.last_rate_kg_ha),
                "tuner": None if self.tuner is None else self.tuner.state(),
                "sections": self.switch.state(),
                "meter_rev": _number_or_list(self.meter_rev),
                "passes": None if self.passes is None else self.passes.state()}

    def set_state(self, state: dict) -> None:
        """Continue from `state` (from `state`, also after JSON: lists for arrays, null for NaN)."""
        self.loop.set_state(state["loop"])
        last = np.atleast_1d(np.asarray(state["last_rate_kg_ha"], dtype=object))
        self.last_rate_kg_ha = np.array([np.nan if v is None else float(v) for v in last])
        if self.tuner is not None:
            self.tuner.set_state(state["tuner"])
        self.switch.set_state(state["sections"])
        self.meter_rev = np.atleast_1d(np.asarray(state["meter_rev"], dtype=float))
        if self.passes is not None and state.get("passes") is not None:
            self.passes.set_state(state["passes"])

    def targets(self, x_m, y_m, heading_rad, speed_m_s, implement_on, s_m=None) -> dict[str, np.ndarray]:
        """Stage 1 over arrays of ticks (shape (n,)); advances the policy's and the sections' memory.

        `s_m` is the distance along the planned path (coverage section control needs it)."""
        states = self.switch.step(x_m, y_m, heading_rad, speed_m_s, implement_on, s_m)
        return self._targets(states)

    def _targets(self, states: SectionStates, rate_kg_ha: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Stage 1 with the sections' states of these ticks known (with the motion the terminal
        sensed, `SectionStates.motion`); advances the policy's memory. `rate_kg_ha` (n, drives): the
        rates the terminal was given (a replayed log's targets) instead of the map's at the landing points."""
        machine = self.machine
        lx, ly, drive_x, drive_y = machine.landing(states.motion, self.look_ahead_s)
        if rate_kg_ha is None:
            found = self.grid.lookup(drive_x, drive_y)
            rate = np.column_stack([self.policy.apply(found.rate_kg_ha[:, d], found.inside[:, d], last)
                                    for d, last in enumerate(self.last_rate_kg_ha)]).reshape(drive_x.shape)
        else:
            rate = np.asarray(rate_kg_ha, dtype=float).reshape(drive_x.shape)
        if len(rate):
            self.last_rate_kg_ha = rate[-1].copy()
        since_s = None if self.passes is None else self.passes.since_open_s(states.actual.any(axis=1))
        target = machine.drive_targets(rate, self._preset(states, since_s))
        steps = {} if states.steps_on is None else {STEPS_KEY: states.steps_on}
        return {"landing_x_m": lx, "landing_y_m": ly, "prescribed_kg_ha": machine.prescribed(rate, states),
                "target_shaft_rpm": machine.combined(target), "drive_rate_kg_ha": rate,
                "drive_target_rpm": target, "drive_speed_m_s": machine.drive_speed_m_s(states.motion),
                "width_on_m": states.width_on_m, "sections_on": states.actual,
                "sections_commanded": states.commanded,
                "drive_open": machine.drive_open(states) & ~machine.shut_off(target), **steps,
                **({} if since_s is None else {OPENING_KEY: self.passes.opening_gain(since_s)})}

    def _preset(self, states: SectionStates, since_open_s) -> SectionStates:
        """The states the targets are computed from: within a pass start's hold the motion's speed
        raised to the machine's preset speed (``[response]``, `vehicle.response.PassClock`)."""
        if not self.response.has_startup:
            return states
        speed = self.passes.target_speed_m_s(states.motion.speed_m_s, since_open_s)
        return dataclasses.replace(states, motion=dataclasses.replace(states.motion, speed_m_s=speed))

    def run_states(self, states: SectionStates, rate_kg_ha: np.ndarray) -> dict[str, np.ndarray]:
        """Both stages over ticks whose section states and rates are given (a replayed log: the gates
        the machine logged, the motion it sensed, the targets it was given, kg/ha (n, drives)); arrays
        keyed as `CONTROL_KEYS`. The same stage 1, loop and metering as `run_track`."""
        rec = self._targets(states, rate_kg_ha)
        return self._closed(rec)

    def _closed(self, rec: dict) -> dict[str, np.ndarray]:
        """The loop over stage 1's `rec` (one chunk) and the product it meters."""
        out = self.loop.run(rec["drive_target_rpm"], context=context_track(rec))
        rec.update(drive_rev=out.shaft_rev, shaft_rpm=self.machine.combined(out.shaft_rpm),
                   shaft_rev=self.machine.combined(out.shaft_rev),
                   current_a=self.machine.combined(out.current_a))
        rec["drive_kg"] = self._metered_kg(rec["drive_rev"], rec["drive_open"], gain=rec.get(OPENING_KEY))
        rec["metered_kg"] = rec["drive_kg"].sum(axis=1) if self.machine.drives > 1 else rec["drive_kg"][:, 0]
        return {key: rec[key] for key in (*CONTROL_KEYS, STEPS_KEY) if key in rec}

    def run_track(self, x_m, y_m, heading_rad, speed_m_s, implement_on, s_m=None,
                  progress=None) -> dict[str, np.ndarray]:
        """Both stages over the next ticks of a measured track; arrays keyed as `CONTROL_KEYS`.

        The track goes through in chunks: stage 1 on a chunk, then the loop over it. With the
        look-ahead tune on, a chunk ends where the tuner moves the look-ahead, and the ticks after it
        are looked up again with the new one, so any split into batches gives the same numbers. The
        sections do not depend on the look-ahead: the switch steps once over each tick (`_SectionsAhead`),
        however often the rate is looked up again.
        """
        n = len(x_m)
        track = tuple(np.asarray(a) for a in (x_m, y_m, heading_rad, speed_m_s))
        sections = _SectionsAhead(self.switch, (*track, implement_on, s_m))
        chunk = RUN_CHUNK if self.tuner is None else TUNE_CHUNK
        parts, start = [], 0
        while not parts or start < n:   # once at least, so that an empty track gives empty arrays
            part = slice(start, min(n, start + chunk))
            rec = self._targets(sections.states(part))
            if self.tuner is not None:
                args = (rec["prescribed_kg_ha"], rec["target_shaft_rpm"], rec["width_on_m"],
                        np.asarray(implement_on, bool)[part])
                keep = self.tuner.plan(*args)
                if keep is not None:     # the look-ahead moves there: look the rest up again
                    rec = {k: v[:keep] for k, v in rec.items()}
                    args = tuple(a[:keep] for a in args)
                    self.last_rate_kg_ha = rec["drive_rate_kg_ha"][-1].copy()
            out = self.loop.run(rec["drive_target_rpm"], context=context_track(rec))
            rec.update(drive_rev=out.shaft_rev, shaft_rpm=self.machine.combined(out.shaft_rpm),
                       shaft_rev=self.machine.combined(out.shaft_rev),
                       current_a=self.machine.combined(out.current_a))
            if self.tuner is not None and len(rec["shaft_rev"]):
                self.tuner.observe(*args, rec["shaft_rev"] * 60.0 / self.period_s)
            parts.append(rec)
            start += len(rec["shaft_rev"])
            if progress is not None:
                progress(start, n)
        rec = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        rec["drive_kg"] = self._metered_kg(rec["drive_rev"], rec["drive_open"], gain=rec.get(OPENING_KEY))
        rec["metered_kg"] = rec["drive_kg"].sum(axis=1) if self.machine.drives > 1 else rec["drive_kg"][:, 0]
        return {key: rec[key] for key in (*CONTROL_KEYS, STEPS_KEY) if key in rec}

    def metered(self, drive_rev, drive_open) -> tuple[np.ndarray, np.ndarray]:
        """Product metered from revolutions a drive turned outside this core's loop (a rate module
        over UDP, `services.aog`), as `run_track` meters its own: each drive's kg (n, drives) and their
        sum (n,). `drive_rev`, `drive_open`: (n, drives) revolutions and whether product reaches the
        ground."""
        kg = self._metered_kg(np.asarray(drive_rev, float), drive_open)
        return kg, kg.sum(axis=1)

    def _metered_kg(self, shaft_rev, applying, drive=None, gain=None) -> np.ndarray:
        """Product metered, kg, from each drive's revolutions (n, drives) and whether its product
        reaches the ground (n, drives): the one place product comes from revolutions; each drive meters
        its share of ``kg_per_rev`` (`services.sim.machines.Machine.drive_share`). `drive`: which drive
        each column is (sweeps' variants run a column per variant and drive); default one per drive.
        `gain` (n,): the opening transient's factor per tick (stage 1's `OPENING_KEY`), if any."""
        # Sections off close the gate: what the shaft turns then stays in the hopper. An underdamped
        # motor can swing briefly backwards when it brakes hard; a roller turning back meters nothing
        # (it does not lift product off the ground), so only forward revolutions count.
        # The product's true constant and flow variability meter it (`vehicle.product`); the terminal
        # computed the target with the configured constant. A closed gate's roller turns all the same.
        forward = np.maximum(shaft_rev, 0.0)
        kg, end_rev = metered_kg(forward, self.machine.kg_per_rev(self.product), self.product, self.seed,
                                 self.meter_rev)
        if self.response.gain != 1.0:   # the machine's steady offset from its target (`[response]`)
            kg = kg * self.response.gain
        if gain is not None:   # a pass start's opening transient (`[response]`)
            kg = kg * np.asarray(gain)[:, None]
        self.meter_rev = np.atleast_1d(end_rev)
        share = self.machine.drive_share if drive is None else self.machine.drive_share[drive]
        return np.where(np.asarray(applying, bool), kg * share, 0.0)


def _number_or_list(per_drive: np.ndarray):
    """Per-drive state as plain data: a number for one metering drive, a list for several."""
    return float(per_drive[0]) if per_drive.size == 1 else per_drive.tolist()


def context_track(rec: dict, part: slice = slice(None), drives=None) -> ContextTrack:
    """The drive's part of the controllers' context (`controller.context`) for ticks `part` of stage 1's
    `rec` (`ControlCore.targets`' keys): each loop's drive's ground speed [m/s] and prescription
    [kg/ha] its target was computed with (`drives`: which drive each loop runs, default one loop per
    drive; one drive: one speed and rate for all loops), and the sections' gates (ticks, sections)."""
    speed, rate = rec["drive_speed_m_s"][part], rec["drive_rate_kg_ha"][part]
    if speed.shape[1] == 1:
        speed, rate = speed[:, 0], rate[:, 0]
    elif drives is not None:
        speed, rate = speed[:, drives], rate[:, drives]
    return ContextTrack(speed, rate, rec["sections_on"][part])


class _SectionsAhead:
    """The section states of a batch's ticks, switched as far as asked for and kept: the look-ahead
    tune looks ticks up again, but the switch is stateful and must step over each tick once."""

    def __init__(self, switch: SectionSwitch, track: tuple):
        self.switch, self.track = switch, track
        self.kept: SectionStates | None = None   # the states of ticks [first, switched)
        self.first = self.switched = 0

    def states(self, part: slice) -> SectionStates:
        """The states of ticks `part` (never reaching back before the ticks asked for last)."""
        if self.kept is not None:   # what lies before `part` is not asked for again
            self.kept = _slice(self.kept, slice(part.start - self.first, None))
            self.first = part.start
        if part.stop > self.switched:
            ahead = slice(self.switched, part.stop)
            x, y, h, v, on, s_m = self.track
            new = self.switch.step(x[ahead], y[ahead], h[ahead], v[ahead], np.asarray(on)[ahead],
                                   None if s_m is None else np.asarray(s_m)[ahead])
            self.kept = new if self.kept is None else _join([self.kept, new])
            self.switched = part.stop
        return _slice(self.kept, slice(part.start - self.first, part.stop - self.first))


def _join(states: list[SectionStates]) -> SectionStates:
    known = all(s.commanded is not None for s in states)
    commanded = np.concatenate([s.commanded for s in states]) if known else None
    steps_on = None if states[0].steps_on is None else np.concatenate([s.steps_on for s in states])
    return SectionStates(np.concatenate([s.actual for s in states]), states[0].widths_m, states[0].offsets_m,
                         np.concatenate([s.pass_index for s in states]), commanded,
                         Motion.join([s.motion for s in states]), steps_on)


def _slice(states: SectionStates, part: slice) -> SectionStates:
    return SectionStates(states.actual[part], states.widths_m, states.offsets_m, states.pass_index[part],
                         None if states.commanded is None else states.commanded[part],
                         states.motion.part(part), None if states.steps_on is None else states.steps_on[part])


# Per tick, shape (n,); ``sections_on`` and ``sections_commanded`` are (n, sections): each section's gate
# and the terminal's command to it (`services.sim.sections.SectionStates`); ``drive_*`` are (n, drives):
# each metering drive's rate at its landing point, target, product and whether it reaches the ground
# (`services.sim.machines`); ``side_steps_on`` (`STEPS_KEY`) too where a spinner's sides shorten in steps
# (`SectionStates.steps_on`). With several drives the shaft keys are the one shaft's that would meter
# what the drives meter together (`Machine.combined`), ``metered_kg`` their sum.
CONTROL_KEYS = ("landing_x_m", "landing_y_m", "prescribed_kg_ha", "target_shaft_rpm", "shaft_rpm",
                "shaft_rev", "current_a", "metered_kg", "width_on_m", "sections_on", "sections_commanded",
                "drive_rate_kg_ha", "drive_target_rpm", "drive_kg", "drive_open")
