"""A run accounted part by part as SUMO drives it: memory set by the map and one part, not by the ticks.

`vrsim run` (`services.sim.streamed`) hands each part of the track it has measured and controlled to
`BoundedAccount.add`; the account lands the product, deposits it on the as-applied raster, adds the
worked area, the transitions and the machine limits, passes each tick's track row to a sink (the
track files, written as they go) and keeps of the ticks only what the outputs show (`services.sim.kept`).

It is the one accounting of a run: the in-process run (`services.sim.run.accounted`: the Python API's
`run` and `control_and_account`, the monitor's report, AgOpenGPS's field) hands it the whole track in
one part and keeps the per-tick arrays (``arrays=True``), so a figure or a fix is written once. Its
figures do not depend on how the track is cut into parts, bit for bit, because it runs the same
functions over stretches that they treat alike:

- a stretch ends where the pass that product lands in changes and the implement is not on across the
  cut (a turn): the strips are ordered by pass and a pass is deposited whole (`maps.AsApplied`), a run
  of work lies whole in one stretch (the worked area), and no rate step's window crosses it;
- each stretch is worked out with the ticks after it that its landing looks at (the delivery delay and
  a tick, and the transitions' hold): ``lookahead`` ticks;
- strips are cut every so many ticks (half a map cell) counted from the run's first tick, at a tick's
  travel known before the drive (`section_landing.tick_travel_m`); the distance along the landing
  path is summed on from the stretch before.

What it keeps per tick: the metered product (8 bytes a tick): a run's total is numpy's pairwise sum over
all its ticks, which a sum of parts does not reproduce to the last bit (the error split's reference
meters, which only the report shows, are summed part by part, their product per cell, both it and their
swept area in single precision (`maps.meter_totals`: a sixth of the memory): equal to the in-process
run's to about 1e-6). The machine-limited ticks keep their landing frames (about 100 bytes each),
whose strips are cut by their own median travel at the end, as the in-process run cuts them; a
pass not yet ended is held until it ends (a stretch is at most a swath and its turn).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vrsim.maps import AsApplied
from vrsim.maps.meter_totals import MeterTotals
from vrsim.services.sim.accounting import (
    Accounts,
    Deposit,
    Setting,
    StageTimer,
    cells_in_field,
    check_world,
    map_figures,
)
from vrsim.services.sim.aslog import run_point_log
from vrsim.services.sim.core import CONTROL_KEYS
from vrsim.services.sim.error_split import REFERENCES, reference_metered_kg
from vrsim.services.sim.kept import SERIES_KEYS, Kept, PathPoints, SeriesWindow
from vrsim.services.sim.landing import Landing, land
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.metrics import limit_metrics, overlap_metrics
from vrsim.services.sim.result import RunResult
from vrsim.services.sim.section_landing import (
    LimitedStrips,
    StripPlan,
    WorkedArea,
    landing_frame,
    landing_pass,
    tick_travel_m,
)
from vrsim.services.sim.sections import STEPS_KEY, SectionStates
from vrsim.services.sim.sections.motion import MotionTrend
from vrsim.services.sim.sections.passes import PassTracker
from vrsim.services.sim.transitions import (
    SETTLE_HOLD_S,
    TransitionEvents,
    rate_steps,
    transition_events,
    transition_figures,
)
from vrsim.services.sim.world import World

# The track's per-tick rows a sink gets (`BoundedAccount`'s ``track_sink``): the true track's, the
# control core's and the landing's (prescribed and applied rate where the product lands).
TRACK_KEYS = ("time_s", "x_m", "y_m", "speed_m_s", "implement_on")
CONTROL_ROW_KEYS = ("target_shaft_rpm", "shaft_rpm", "current_a", "sections_on")


class BoundedAccount:
    """The accounts of a run fed part by part (see the module docstring).

    Parameters
    ----------
    world : World
    timer : StageTimer
        The run's; the accounting's time goes to ``metrics_s``.
    started_unix : float
        When the run started (the as-applied log's clock).
    expected_ticks : float
        About how many ticks the drive has (the path points' thinning).
    track_sink : callable, optional
        ``track_sink(rows)`` with each stretch's per-tick rows: a dict of `TRACK_KEYS` and
        `CONTROL_ROW_KEYS` arrays, ``prescribed_kg_ha`` and ``applied_kg_ha`` (the landing's).
    references : bool
        Also deposit the error split's reference meters (``reference_figures`` of the result).
    arrays : bool
        Keep the per-tick arrays the Python API offers (`services.sim.run.accounted`, the in-process
        run): the result holds the whole track, the control core's arrays, the sections' gates and
        where each tick's product landed, and its outputs' points and log are read off them
        (``RunResult.kept``) instead of kept as the parts come.
    """

    def __init__(self, world: World, timer: StageTimer, started_unix: float, expected_ticks: float = 0,
                 track_sink=None, references: bool = False, arrays: bool = False):
        sc, grid = world.scenario, world.grid
        imp = sc.implement
        self.world, self.timer, self.started_unix, self.track_sink = world, timer, started_unix, track_sink
        self.delay_s, self.period_s = imp.delivery_delay_s, sc.timing.control_period_s
        self.cell_m, self.tick_m = min(grid.cell_size), tick_travel_m(sc)
        self.lookahead = int(math.ceil(max(self.delay_s + self.period_s, SETTLE_HOLD_S) / self.period_s)) + 3
        self.acc = AsApplied(grid)
        self.owned = None   # the ground each pass owns, for a machine whose deposition lays beyond it
        self.worked = WorkedArea(grid)
        self.machine = machine_for(imp, world.field.polygon)
        # The field's cells, for the result: found now, while SUMO drives, not after the drive.
        self.in_field = cells_in_field(grid, world.field.polygon)
        # The reference meters' totals (`maps.meter_totals`: their product per cell, their swept area
        # shared while they put product on the same items, in single precision), not an `AsApplied` each.
        self.refs = MeterTotals(grid, len(REFERENCES)) if references else None
        # The spread pattern's reference: the unclipped product on the sections' strips (only a kind
        # whose footprint is not strips needs its own raster: for the others it is the first reference).
        self.ref_strips = MeterTotals(grid, 1) if references else None
        self.passes = PassTracker()
        self.pending: list = []   # the parts of the ticks not yet accounted, from tick `first` of the run
        self.first = 0
        self.distance_m = 0.0     # the landing path's length so far
        self.last_pass = -1       # the landing pass of the last tick accounted
        self.metered: list = []   # per stretch: the run's metered kg
        self.ref_kg = [0.0] * len(REFERENCES)  # the reference meters' product so far ...
        self.ref_rev = [0.0] * len(REFERENCES)  # ... and where their shafts stand
        self.ref_motion = MotionTrend(self.period_s)  # the sensed motion the references' targets read
        self.events: list = []    # per stretch: its transition events
        self.limited = self.applying = 0
        self.limited_ticks: list = []   # per stretch: the limited ticks' landing frames
        self.path = PathPoints.for_ticks(expected_ticks)
        self.series = SeriesWindow()
        self.logs: list = []
        self.last_row: dict | None = None   # the last tick accounted, for the log's thinning
        # With `arrays`: the parts as given (track, measured speed, control), and per stretch its
        # ticks' landing and their limited and applying flags.
        self.arrays = [] if arrays else None
        self.landings: list = []
        self.flags: list = []

    def add(self, track: dict, measured_speed_m_s, control: dict) -> None:
        """The next ticks: the true track (`vehicle.track_on_path`), the measured ground speed and the
        control core's arrays (`services.sim.core.CONTROL_KEYS`)."""
        with self.timer.stage("metrics_s"):
            part = dict(track, measured_speed_m_s=np.asarray(measured_speed_m_s), **control)
            part["pass_index"] = self.passes.step(track["heading_rad"], track["implement_on"])
            if self.arrays is not None:
                self.arrays.append((track, measured_speed_m_s, control, part["pass_index"]))
            self.pending.append(part)
            # Only what finds the cut is joined as the parts come (a swath spans several of them).
            cut = self._last_cut(self._joined(("time_s", "pass_index", "implement_on")))
            if cut:
                self._account(cut, self._joined(part))

    def result(self, measured: tuple | None = None) -> RunResult:
        """Account for the ticks still pending (the drive has ended) and return the run's result;
        `measured`: with ``arrays``, the measured x, y (m) and ground speed (m/s) per tick of the whole
        run, for the result (None: the parts' measured speed, and no measured x, y)."""
        with self.timer.stage("metrics_s"):
            if self.pending:
                p = self._joined(self.pending[0])
                if len(p["time_s"]):
                    self._account(len(p["time_s"]), p)
            return self._result(measured)

    # --- stretches -------------------------------------------------------------------------------
    def _joined(self, keys) -> dict:
        """The pending ticks' arrays of `keys`, the parts joined."""
        if len(self.pending) == 1:
            return self.pending[0]
        return {k: np.concatenate([part[k] for part in self.pending]) for k in keys}

    def _last_cut(self, p: dict) -> int:
        """The last tick of the pending ticks `p` before which a stretch may end (0: none yet): the
        landing pass changes there, the implement is not on across it, and the look-ahead after it is
        there."""
        n = len(p["time_s"]) - self.lookahead
        if n < 2:
            return 0
        lp = self._landing_passes(p, n)
        on = np.asarray(p["implement_on"], bool)[:n]
        ok = np.flatnonzero((lp[1:] > lp[:-1]) & ~(on[1:] & on[:-1])) + 1
        return int(ok[-1]) if ok.size else 0

    def _landing_passes(self, p: dict, n: int) -> np.ndarray:
        """The landing pass of the first `n` pending ticks, the passes before them counted."""
        filled = np.maximum(np.asarray(p["pass_index"]), self.last_pass)
        return landing_pass(p["time_s"], filled, self.delay_s, np.arange(n))

    def _account(self, n: int, p: dict) -> None:
        """Account for the first `n` pending ticks (a stretch) with the look-ahead after them."""
        world, imp = self.world, self.world.scenario.implement
        end = min(len(p["time_s"]), n + self.lookahead)
        w = {k: v[:end] for k, v in p.items()}
        states = SectionStates(np.asarray(w["sections_on"], bool), imp.section_widths, imp.section_offsets_m,
                               w["pass_index"], w.get("sections_commanded"), steps_on=w.get(STEPS_KEY))
        metered = w["metered_kg"]
        landing = land(world.grid, w, metered, w["width_on_m"], self.delay_s, self.period_s)
        distance = np.cumsum(np.append(self.distance_m, landing.strip_length_m))[1:]
        ticks = np.arange(n)
        plan = self.machine.deposition(w, states, self.delay_s, self.period_s, self.cell_m, ticks,
                                       self.tick_m, self.first)
        product_kg = self.machine.deposit_kg(w)
        product = plan.mass_kg(product_kg)
        # The reference meters' product on the same footprint: its samples and sub-cells worked out once.
        others = () if self.refs is None else self._references(w, states, n, plan)
        self.acc.deposit(plan.footprint(), product, pass_index=plan.pass_index, others=others)
        self._own(w, states, ticks, product_kg)
        self.metered.append(metered[:n].copy())   # a copy: not a view holding the look-ahead's arrays
        self.worked.add(w, imp.width_m, n)
        on = np.asarray(w["implement_on"], bool)
        steps = rate_steps(landing.prescribed_kg_ha[:n], on[:n])
        self.events.append(transition_events(w["time_s"], distance, landing.prescribed_kg_ha,
                                             landing.applied_kg_ha, on, steps, upto=n))
        self._limits(w, states, n)
        if self.arrays is None:
            self._outputs(w, landing, n)
        else:
            self.landings.append((dataclasses.replace(landing, distance_m=distance), n))
        self.distance_m = float(distance[n - 1])
        self.last_pass = int(max(self.last_pass, np.max(w["pass_index"][:n], initial=-1)))
        self.first += n
        self.pending = [{k: v[n:] for k, v in p.items()}]

    def _references(self, w: dict, states: SectionStates, n: int, plan) -> list:
        """The error split's reference meters' product of the stretch through the run's `plan`, as
        `services.sim.error_split` meters it: each drive's target, at its own ground speed in turns (the
        sensed motion carried from stretch to stretch): a (raster, kg per strip) pair each, to deposit
        beside the run's own product (`maps.AsApplied.deposit`'s ``others``)."""
        motion = self.ref_motion.step(w["x_m"][:n], w["y_m"][:n], w["heading_rad"][:n],
                                      w["measured_speed_m_s"][:n])
        sensed = SectionStates(states.actual[:n], states.widths_m, states.offsets_m, states.pass_index[:n],
                               None, motion, None if states.steps_on is None else states.steps_on[:n])
        control = {k: w[k][:n] for k in ("drive_target_rpm", "drive_rate_kg_ha")}
        metered = []
        for j, reference in enumerate(REFERENCES):
            ref, self.ref_rev[j] = reference_metered_kg(self.world, self.machine, sensed, control, *reference,
                                                        start_rev=self.ref_rev[j])
            metered.append(ref[:, 0] if self.machine.drives == 1 else ref)
            self.ref_kg[j] += float(ref.sum())
            if j == 0 and not isinstance(plan, StripPlan):
                strips = StripPlan.of(w, states, self.delay_s, self.period_s, self.cell_m, np.arange(n),
                                      self.tick_m, self.first)
                self.ref_strips.deposit(strips.footprint(), strips.mass_kg(ref.sum(axis=1)))
        # The meters' strips in one product with the plan's map, a column each (each column's sums as
        # a product of its own).
        return [(self.refs, plan.mass_kg(np.stack(metered, axis=-1)))]

    def _limits(self, w: dict, states: SectionStates, n: int) -> None:
        """Count the applying and the machine-limited ticks, and keep the limited ones' landing frames."""
        applying = w["width_on_m"][:n] > 0
        window = {k: w[k][:n] for k in CONTROL_KEYS if k in w}
        limited = self.machine.limited(window, self.world.scenario.product) & applying
        self.applying += int(np.count_nonzero(applying))
        self.limited += int(np.count_nonzero(limited))
        if self.arrays is not None:
            self.flags.append((limited, applying))
        idx = np.flatnonzero(limited)
        if idx.size:
            frame = landing_frame(w, self.delay_s, self.period_s, idx)
            passes = landing_pass(w["time_s"], states.pass_index, self.delay_s, idx)
            self.limited_ticks.append((frame, passes, states.actual[idx], self.first + idx,
                                       w["metered_kg"][idx]))

    def _outputs(self, w: dict, landing: Landing, n: int) -> None:
        """The stretch's track rows to the sink, and what the pictures and the log keep."""
        rows = {k: w[k][:n] for k in TRACK_KEYS + CONTROL_ROW_KEYS}
        rows.update(prescribed_kg_ha=landing.prescribed_kg_ha[:n], applied_kg_ha=landing.applied_kg_ha[:n])
        if self.track_sink is not None:
            self.track_sink(rows)
        self.path.add(rows["x_m"], rows["y_m"])
        self.series.add({k: rows[k] for k in SERIES_KEYS}, rows["implement_on"])
        self._log(w, rows, n)

    def _log(self, w: dict, rows: dict, n: int) -> None:
        """The stretch's records of the as-applied log, thinned as the whole run's: the last tick of the
        stretch before goes first (the first record of a thinning is kept) and is dropped again."""
        part = {k: rows[k] for k in ("time_s", "x_m", "y_m", "speed_m_s", "implement_on", "sections_on",
                                     "applied_kg_ha")}
        # The log's target is the control core's (the prescription at the predicted landing point).
        part.update(heading_rad=w["heading_rad"][:n], width_on_m=w["width_on_m"][:n],
                    target_kg_ha=w["prescribed_kg_ha"][:n])
        last, self.last_row = self.last_row, {k: v[-1:] for k, v in part.items()}
        if last is not None:
            part = {k: np.concatenate([last[k], part[k]]) for k in part}
        control = {"width_on_m": part["width_on_m"], "prescribed_kg_ha": part["target_kg_ha"],
                   "sections_on": part["sections_on"]}
        log = run_point_log(self.world, part, control, part["applied_kg_ha"], self.started_unix,
                            self.world.scenario.output.log_rate_hz)
        self.logs.append(log if last is None else _dropped_first(log))

    def _own(self, w: dict, states: SectionStates, ticks: np.ndarray, product_kg) -> None:
        """The product of `ticks` (`product_kg`: `Machine.deposit_kg` of the window `w`) on the ground
        each pass owns (`Machine.ownership`), for a machine whose deposition lays beyond it: its overlap
        is the run's overlap figures."""
        own = self.machine.ownership(w, states, self.delay_s, self.period_s, self.cell_m, ticks, self.tick_m,
                                     self.first)
        if own is None:
            return
        if self.owned is None:
            self.owned = AsApplied(self.world.grid)
        self.owned.deposit(own.footprint(), own.mass_kg(product_kg), pass_index=own.pass_index)

    # --- the end ---------------------------------------------------------------------------------
    def _result(self, measured: tuple | None) -> RunResult:
        world, grid, acc = self.world, self.world.grid, self.acc
        acc.close_pass()   # the drive is over: each read below no longer adds the last pass's raster
        in_field = self.in_field
        worked = self.worked.fraction()
        if self.arrays is None:   # a run's outputs read its raster per cell: the sub-cells given back
            acc.finish()
        references = self._reference_figures(worked)   # their rasters let go before the run's figures
        cover = acc.coverage_fraction
        # numpy's pairwise sum over the whole run, as the in-process run's.
        metered_kg = float(np.concatenate([np.zeros(0), *self.metered]).sum())
        limited_cover = self._limited_coverage()
        # Each raster figure read once (each read sums the sub-cells again).
        owned = acc if self.owned is None else self.owned
        owned.close_pass()
        whole = self._arrays() if self.arrays is not None else None
        track, speed, control, landing, limited, applying_ticks, states = whole or (None,) * 7
        deposit = Deposit(None if whole is None else control["metered_kg"],
                          None if whole is None else landing.applied_kg_ha, acc.applied_kg_ha, cover,
                          owned.overlap_fraction, owned.overlap_kg, acc.outside_kg, limited_cover)
        d = deposit
        steps = None if whole is None else rate_steps(landing.prescribed_kg_ha,
                                                      np.asarray(track["implement_on"], bool))
        setting = Setting(world, track, landing, in_field, worked, limited, applying_ticks, steps,
                          check_world(world, in_field), self.first, self.distance_m)
        # The counts of limited and applying ticks as `limit_metrics` counts them over a run's arrays.
        applying = np.ones(self.applying, bool)
        limits = limit_metrics(np.arange(self.applying) < self.limited, applying, limited_cover, cover,
                               in_field)
        accounts = Accounts(setting, deposit,
                            map_figures(grid, in_field, d.applied_kg_ha, cover, metered_kg, d.outside_kg,
                                        worked),
                            transition_figures(TransitionEvents.joined(self.events)),
                            overlap_metrics(cover, d.overlap_fraction, d.overlap_kg, worked, in_field,
                                            grid.rates_kg_ha),
                            limits, self.timer.timing())
        if whole is not None:   # the arrays' own outputs (`RunResult.kept`)
            x_m, y_m, speed = measured or (None, None, speed)
            return RunResult(x_m, y_m, speed, control, states, acc, accounts, self.started_unix,
                             reference_figures=references)
        kept = Kept(self.path.xy(), self.series.finish(), _joined_logs(self.logs))
        return RunResult(None, None, None, None, None, acc, accounts, self.started_unix,
                         reference_figures=references, kept_parts=kept)

    def _reference_figures(self, worked: np.ndarray) -> list | None:
        """The reference meters' map figures (the spread pattern's stage first), their rasters then let
        go (the result keeps only the figures); None without references."""
        refs, strips, grid, in_field = self.refs, self.ref_strips, self.world.grid, self.in_field
        if refs is None:
            return None
        self.refs = self.ref_strips = None
        meters = [map_figures(grid, in_field, refs.applied_kg_ha(j), refs.coverage_fraction(j),
                              self.ref_kg[j], refs.outside_kg(j), worked) for j in range(refs.meters)]
        # The spread pattern's stage: the first meter's own figures where the kind lays strips.
        pattern = meters[0] if not strips.items else map_figures(
            grid, in_field, strips.applied_kg_ha(0), strips.coverage_fraction(0), self.ref_kg[0],
            strips.outside_kg(0), worked)
        return [pattern, *meters]

    def _arrays(self) -> tuple:
        """The whole run's per-tick arrays (``arrays``): the track, the measured speed, the control
        core's arrays, where each tick's product landed, the limited and the applying ticks and the
        sections' states."""
        imp, parts = self.world.scenario.implement, self.arrays
        track, speed, control, pass_index = (parts[0] if len(parts) == 1 else
                                             [_concatenated(column) for column in zip(*parts, strict=True)])
        if self.landings:
            landing = Landing(*(np.concatenate([getattr(g, f.name)[:n] for g, n in self.landings])
                                for f in dataclasses.fields(Landing)))
        else:   # no tick
            landing = land(self.world.grid, track, control["metered_kg"], control["width_on_m"],
                           self.delay_s, self.period_s)
        limited, applying = ((np.concatenate(f) for f in zip(*self.flags, strict=True)) if self.flags
                             else (np.zeros(0, bool), np.zeros(0, bool)))
        states = SectionStates(np.asarray(control["sections_on"], bool), imp.section_widths,
                               imp.section_offsets_m, pass_index, control.get("sections_commanded"),
                               steps_on=control.get(STEPS_KEY))
        return track, speed, control, landing, limited, applying, states

    def _limited_coverage(self) -> np.ndarray:
        """`section_landing.limited_coverage` of the limited ticks kept."""
        grid, imp = self.world.grid, self.world.scenario.implement
        if not self.limited_ticks:
            return LimitedStrips.of_plan(None, grid).coverage(np.zeros((0, 1)))[0]
        frames, passes, actual, numbers, metered = zip(*self.limited_ticks, strict=True)
        frame = tuple(np.concatenate(f) for f in zip(*frames, strict=True))
        numbers = np.concatenate(numbers)
        states = SectionStates(np.zeros((0, imp.sections), bool), imp.section_widths, imp.section_offsets_m,
                               np.zeros(0, np.int64))
        plan = StripPlan.of_frame(frame, np.concatenate(passes), np.concatenate(actual), numbers, states,
                                  self.cell_m, np.arange(numbers.size))
        return LimitedStrips.of_plan(plan, grid).coverage(np.concatenate(metered)[:, None])[0]


def _concatenated(parts: list):
    """Consecutive parts joined: arrays end to end, dicts of arrays key by key."""
    if isinstance(parts[0], dict):
        return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in parts[0]}
    return np.concatenate([np.asarray(p) for p in parts])


def _dropped_first(log):
    """`log` without its first record."""
    from vrsim.maps.pointlog import COLUMNS

    return dataclasses.replace(log, **{name: getattr(log, name)[1:] for name in COLUMNS})


def _joined_logs(logs: list):
    """One log of consecutive parts' logs (None: no part)."""
    from vrsim.maps.pointlog import COLUMNS

    if not logs:
        return None
    return dataclasses.replace(logs[0], **{name: np.concatenate([getattr(g, name) for g in logs])
                                           for name in COLUMNS})
