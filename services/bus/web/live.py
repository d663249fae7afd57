"""What the live page shows, as state that the bus threads update and the web server reads in frames.

Pure: no zenoh, no HTTP. The bus side calls `LiveView.on_pose` / `on_shaft` / `on_rate` with decoded
messages (every message, at whatever rate the run goes); the web side calls `LiveView.frame` at most
every `FRAME_S` and hands each browser `LiveView.delta` since what that browser last got. A browser
that falls behind does not make anything queue up: its next delta covers everything since its last
one (the cells painted since, the latest pose/shaft/rate, the chart points still held).

The as-applied layer is accumulated here, server side, because the browser gets at most 20 frames a
second while a lockstep run carries some 15,000 rate samples a second: only the server sees them all.
It is the live view's layer, not the report's: each rate sample's applied rate (metered kg over the
area its sections covered in the period) is spread across each section whose gate was open (the
sample's ``section_mask``, placed with the implement's section widths: samples wait until the run's
scenario is known, `LiveView.set_run_info`), at the landing point the controller predicted, through
the run's deposition engine (`services.bus.web.layer`); a cell shows the mean of the samples over it.
The report's raster (product put where it really landed on the true path, area-weighted) is what the
monitor computes the metrics on; the two agree to within the GNSS error and a cell's edge.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from vrsim.common.section_masks import sections_from_masks
from vrsim.services.bus.web.layer import AppliedLayer, ViewGrid

FRAME_S = 0.05  # at most 20 frames a second, whatever the simulation speed
HISTORY_POINTS = 600  # chart points kept: 30 s of frames at 20 a second
HEADING_RING = 1 << 18  # ticks of pose heading kept to orient the rate samples that follow them: on a
# loaded machine the rate stream can lag the pose stream by seconds of lockstep ticks (8,192, half a
# second at 15,000 ticks/s, lost samples under load); 4 MB for about 17 s
UNSECTIONED_TICKS = 65536  # rate samples kept until the run's sections are known (then the oldest go)
STREAMS = ("pose", "shaft", "rate")


# The fields of each stream the view reads: live, and from the monitor's records (for the charts too).
FIELDS = {"pose": ("tick", "heading_rad"), "shaft": ("tick",),
          "rate": ("tick", "landing_x_m", "landing_y_m", "width_on_m", "section_mask", "applied_kg_ha",
                   "implement_on")}
RECORD_FIELDS = {"pose": FIELDS["pose"], "shaft": ("tick", "target_shaft_rpm", "shaft_rpm"),
                 "rate": (*FIELDS["rate"], "time_s", "prescribed_kg_ha")}


@dataclass(frozen=True)
class Batch:
    """Records of one stream as columns (`messages.decode_columns`): ``cols`` holds ``tick`` and the
    fields the view reads, arrays of one length in the order they came; ``last`` is the last record
    whole (as `Message.to_dict`), what the page shows."""

    run_id: str
    cols: dict
    last: dict | None = None

    @property
    def tick(self) -> np.ndarray:
        return self.cols["tick"]

    def take(self, which) -> Batch:
        return Batch(self.run_id, {k: _take(v, which) for k, v in self.cols.items()}, self.last)

    def extend(self, other: Batch) -> Batch:
        return Batch(self.run_id, {k: np.concatenate([v, other.cols[k]]) for k, v in self.cols.items()},
                     other.last)


def _take(column, which):
    """``column[which]`` for an array or a list (str fields come as lists, `messages.decode_columns`)."""
    if isinstance(column, list):
        return np.asarray(column, dtype=object)[which].tolist()
    return column[which]


@dataclass(frozen=True)
class SectionGeometry:
    """The implement's sections, left to right: each one's width and its centre's offset to the left
    of the implement's centre, m (`vehicle.Implement.section_widths`, ``section_offsets_m``)."""

    widths_m: np.ndarray
    offsets_m: np.ndarray

    def strips(self, masks, width_on_m):
        """Per open section of each sample: (sample index, strip width, strip offset), arrays of one
        length. A batch holding a mask that is not one of these sections' is left out whole (the
        bus is untrusted; `common.section_masks.sections_from_masks` checks the masks)."""
        try:
            on = sections_from_masks(masks, self.widths_m.size)
        except ValueError:
            on = np.zeros((len(masks), self.widths_m.size), bool)
        on &= (np.asarray(width_on_m, dtype=np.float64) > 0)[:, None]
        sample, section = np.nonzero(on)
        return sample, self.widths_m[section], self.offsets_m[section]


class LiveView:
    """Everything the page shows: the run, the latest pose/shaft/rate, the applied layer, the chart
    history, scenario status and report. Thread-safe; see the module's docstring for the data flow.

    ``epoch`` counts the changes after which a browser must start over from a full `hello` (a new run,
    a new map, a catch-up from the monitor's records that filled in the past); ``seq`` counts frames.
    """

    def __init__(self, history_points: int = HISTORY_POINTS):
        self.lock = threading.Lock()
        self.epoch = 0
        self.seq = 0
        self.dirty = False
        self.history: deque = deque(maxlen=history_points)  # (seq, [time_s, target, shaft, rx, applied])
        self.map: dict | None = None  # {"info", "grid", "version"}
        self.layer: AppliedLayer | None = None
        self.status: dict | None = None
        self.status_seq = -1
        self.report: dict | None = None
        self.report_seq = -1
        self.left: deque = deque(maxlen=32)  # runs this view moved on from: never shown again
        self.run_id = ""
        self._reset_run("")

    def _reset_run(self, run_id: str) -> None:
        if self.run_id:
            self.left.append(self.run_id)
        self.run_id = run_id
        self.run: dict = {"run_id": run_id}  # scenario, clock, field boundary and path, once known
        self.sections: SectionGeometry | None = None  # the implement's sections, once known
        self.unsectioned: list = []  # (rates, heading) oriented, waiting for the sections
        self.latest: dict = {s: None for s in STREAMS}
        # First tick seen live, per stream; for rate: painted live from (`set_map` moves it on).
        self.first_tick: dict = {s: None for s in STREAMS}
        self.backfilled_to = 0  # rate ticks below this were painted from the monitor's records
        self.catchup = {"state": "none", "ticks": 0}
        self.catchup_points: list = []  # chart points from the records, added to the history when done
        self.heading_tick = np.full(HEADING_RING, -1, dtype=np.int64)
        self.heading_rad = np.zeros(HEADING_RING)
        self.waiting: Batch | None = None  # rate samples whose pose has not come yet
        self.unpainted: list = []  # oriented samples for the next frame to paint
        self.newest_pose_tick = -1
        self.newest_rate_tick = -1
        self.unoriented = 0  # rate samples left unpainted: their pose never came
        self.history.clear()
        self.report, self.report_seq = None, -1
        if self.map is not None:
            self.layer = AppliedLayer(self.map["grid"])

    def _changed_run(self, stream: str, batch: Batch) -> str | None:
        """Start over on a message of another run; returns that run's id (None: same run)."""
        new = batch.run_id != self.run_id
        if new:
            self._reset_run(batch.run_id)
            self.epoch += 1
        if self.first_tick[stream] is None:
            self.first_tick[stream] = int(batch.tick[0])
        return batch.run_id if new else None

    # ---------------------------------------------------------------- from the bus
    def on_pose(self, batch: Batch) -> str | None:
        """One pose message; returns the run id when it starts a run this view had not seen (so for
        `on_shaft` and `on_rate`)."""
        return self._received("pose", batch, self._orient)

    def on_shaft(self, batch: Batch) -> str | None:
        return self._received("shaft", batch, lambda b: None)

    def on_rate(self, batch: Batch) -> str | None:
        return self._received("rate", batch, self._paint_new)

    def _paint_new(self, rates: Batch) -> None:
        """Paint the live samples from the live boundary on: ticks before ``first_tick["rate"]`` (the
        first seen live, or the first after a new grid, `set_map`) and before ``backfilled_to`` are
        the monitor's records' to paint (`backfill`), so no tick is painted from both."""
        self.newest_rate_tick = max(self.newest_rate_tick, int(rates.tick.max()))
        self._paint_oriented(rates.take(rates.tick >= max(self.backfilled_to, self.first_tick["rate"])))

    def _received(self, stream: str, batch: Batch, use) -> str | None:
        with self.lock:
            if batch.run_id in self.left:  # a late message of a run that is over (or a forged one)
                return None
            new = self._changed_run(stream, batch)
            use(batch)
            self.latest[stream] = batch.last
            self.dirty = True
            return new

    def _orient(self, poses: Batch) -> None:
        """Keep the poses' headings by tick, and paint the rate samples that were waiting for them."""
        slot = poses.tick % HEADING_RING
        self.heading_tick[slot] = poses.tick
        self.heading_rad[slot] = poses.cols["heading_rad"]
        self.newest_pose_tick = max(self.newest_pose_tick, int(poses.tick.max()))
        if self.waiting is not None:
            waiting, self.waiting = self.waiting, None
            self._paint_oriented(waiting)

    def _paint_oriented(self, rates: Batch) -> None:
        """Paint the samples whose tick's pose (heading) is known; the others wait for it (the vehicle
        publishes a tick's pose before the controller its rate, but they reach here on two paths)."""
        slot = rates.tick % HEADING_RING
        known = self.heading_tick[slot] == rates.tick
        self._paint(rates.take(known), self.heading_rad[slot[known]])
        # Poses come in tick order: a sample whose pose should have come already never gets one.
        later = ~known & (rates.tick > self.newest_pose_tick)
        self.unoriented += int(np.count_nonzero(~known & ~later))
        if later.any():
            waiting = rates.take(later) if self.waiting is None else self.waiting.extend(rates.take(later))
            self.waiting = waiting.take(slice(-HEADING_RING, None))

    def _paint(self, rates: Batch, heading: np.ndarray) -> None:
        """Queue oriented samples; `_flush` paints them in one go (numpy's per-call cost, paid per
        message, would be most of the work: a lockstep run sends some 300 rate messages a second)."""
        if self.layer is not None and len(rates.tick):
            c = rates.cols
            width = np.where(c["implement_on"], c["width_on_m"], 0.0)
            x, y, rate = c["landing_x_m"], c["landing_y_m"], c["applied_kg_ha"]
            if self.sections is None:   # the run's implement not known yet: wait for it
                self.unsectioned.append((rates, heading))
                while sum(len(r.tick) for r, _ in self.unsectioned) > UNSECTIONED_TICKS:
                    self.unoriented += len(self.unsectioned.pop(0)[0].tick)
                return
            i, strip_w, strip_off = self.sections.strips(c["section_mask"], width)
            self.unpainted.append((x[i], y[i], heading[i], strip_w, strip_off, rate[i]))

    def _flush(self, seq: int) -> None:
        if self.unpainted and self.layer is not None:
            self.layer.paint(seq, *(np.concatenate(col) for col in zip(*self.unpainted, strict=True)))
        self.unpainted = []

    def backfill(self, poses: Batch, shafts: Batch, rates: Batch, stride: int) -> int:
        """Records of the run's past from the monitor (ticks before those seen live): paint the rates
        (oriented by the poses of the same ticks) and keep every ``stride``-th tick for the chart
        history. Returns the ticks painted."""
        with self.lock:
            if rates.run_id != self.run_id:
                return 0
            live = self.first_tick["rate"]
            rates = rates.take((rates.tick >= self.backfilled_to) & (rates.tick < (live if live is not None
                                                                                   else np.inf)))
            if not len(rates.tick):
                return 0
            self._paint(rates, _at(poses, rates.tick, "heading_rad"))
            self._flush(self.seq + 1)
            self.backfilled_to = int(rates.tick[-1]) + 1
            some = rates.take(rates.tick % stride == 0)
            columns = [some.cols["time_s"], _at(shafts, some.tick, "target_shaft_rpm"),
                       _at(shafts, some.tick, "shaft_rpm"), some.cols["prescribed_kg_ha"],
                       some.cols["applied_kg_ha"]]
            self.catchup_points += [[_json(v) for v in row] for row in zip(*columns, strict=True)]
            self.catchup["ticks"] += len(rates.tick)
            self.dirty = True
            return len(rates.tick)

    def set_catchup(self, run_id: str, state: str, note: str = "") -> None:
        with self.lock:
            if run_id == self.run_id:
                self.catchup.update(state=state, note=note)
                if state in ("done", "failed"):
                    room = self.history.maxlen - len(self.history)
                    older = self.catchup_points[-room:] if room > 0 else []
                    self.history.extendleft((0, p) for p in reversed(older))  # oldest first again
                    self.catchup_points = []
                    self.epoch += 1  # browsers start over with the past filled in
                self.dirty = True

    def adopt_run(self, run_id: str) -> bool:
        """Show ``run_id`` (a run found through scenario status, before any of its messages)."""
        with self.lock:
            if run_id == self.run_id or run_id in self.left:  # a status older than the messages
                return False
            self._reset_run(run_id)
            self.epoch += 1
            self.dirty = True
            return True

    def set_run_info(self, run_id: str, info: dict, sections: SectionGeometry | None = None) -> None:
        """What the run's scenario says (shown on the page), and its implement's sections (where the
        rate samples' section masks paint from now on)."""
        with self.lock:
            if run_id == self.run_id:
                self.run.update(info)
                if sections is not None and self.sections is None:
                    self.sections = sections
                    waiting, self.unsectioned = self.unsectioned, []
                    for rates, heading in waiting:
                        self._paint(rates, heading)
                self.epoch += 1
                self.dirty = True

    def set_map(self, info: dict, grid: ViewGrid, version: int) -> bool:
        """The map served now. On another grid the applied layer starts over, and from the next rate
        tick on it is painted live; returns True when ticks before that need painting from the
        monitor's records (a run's map is loaded before it starts, but seen here after its first
        messages)."""
        with self.lock:
            self.map = {"info": info, "grid": grid, "version": version}
            self.epoch += 1
            self.dirty = True
            if self.layer is not None and self.layer.grid == grid:
                return False
            self.layer = AppliedLayer(grid)
            # Every rate tick seen so far is the records' to paint on the new grid, those held back
            # (waiting for their pose or for the run's sections) too: dropped here, not painted twice.
            self.unpainted, self.unsectioned, self.waiting = [], [], None
            self.backfilled_to = 0
            seen = self.newest_rate_tick >= 0
            self.first_tick["rate"] = self.newest_rate_tick + 1 if seen else None
            return seen or self.catchup["state"] != "none"

    def set_status(self, status: dict) -> None:
        with self.lock:
            if status != self.status:
                self.status, self.status_seq = status, self.seq + 1
                self.dirty = True

    def set_report(self, run_id: str, report: dict) -> None:
        with self.lock:
            if run_id == self.run_id:
                self.report, self.report_seq = report, self.seq + 1
                self.dirty = True

    # ---------------------------------------------------------------- to the browsers
    def frame(self) -> int | None:
        """Close a frame if anything changed since the last; returns its seq (None: nothing new)."""
        with self.lock:
            if not self.dirty:
                return None
            self.seq += 1
            self.dirty = False
            self._flush(self.seq)
            if self.latest["rate"] is not None or self.latest["shaft"] is not None:
                point = _point_dicts(self.latest["shaft"], self.latest["rate"])
                if not self.history or self.history[-1][1] != point:
                    self.history.append((self.seq, point))
            return self.seq

    def hello(self) -> dict:
        """Everything, for a browser that (re)starts: ``{"type": "hello", ...}``."""
        with self.lock:
            return self._doc("hello", -1)

    def delta(self, since_seq: int, since_epoch: int) -> dict:
        """What changed after frame ``since_seq``; a `hello` when the epoch moved on since."""
        with self.lock:
            return self._doc("hello" if since_epoch != self.epoch else "frame", since_seq)

    def _doc(self, kind: str, since: int) -> dict:
        since = -1 if kind == "hello" else since
        doc = {"type": kind, "epoch": self.epoch, "seq": self.seq, "run_id": self.run_id,
               "pose": self.latest["pose"], "shaft": self.latest["shaft"], "rate": self.latest["rate"],
               "points": [p for s, p in self.history if s > since],
               "applied": self.layer.since(since) if self.layer is not None else {"i": [], "v": []}}
        if kind == "hello":
            doc.update(run=self.run, map_version=self.map["version"] if self.map else None,
                       catchup=self.catchup)
        if self.status_seq > since:
            doc["status"] = self.status
        if self.report_seq > since:
            doc["report"] = self.report
        return doc

    def run_state(self) -> tuple[str, dict]:
        with self.lock:
            return self.run_id, dict(self.first_tick)


def _at(batch: Batch, ticks: np.ndarray, field: str) -> np.ndarray:
    """``batch``'s ``field`` at ``ticks`` (NaN where it has no such tick); its ticks ascend."""
    i = np.clip(np.searchsorted(batch.tick, ticks), 0, max(len(batch.tick) - 1, 0))
    if not len(batch.tick):
        return np.full(len(ticks), np.nan)
    return np.where(batch.tick[i] == ticks, batch.cols[field][i], np.nan)


def _json(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _point_dicts(shaft: dict | None, rate: dict | None) -> list:
    time_s = (rate or shaft)["time_s"]
    return [time_s, shaft["target_shaft_rpm"] if shaft else None, shaft["shaft_rpm"] if shaft else None,
            rate["prescribed_kg_ha"] if rate else None, rate["applied_kg_ha"] if rate else None]
