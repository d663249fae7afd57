"""The web service's side of the bus: subscriptions that feed the `LiveView`, the map, the run's field
and path, a catch-up from the monitor's records for a run joined late, status and report polling,
and the operator's actions.

Everything read from the bus is untrusted: messages are decoded by their schema
(`messages.decode_batch`), the map's info by `ViewGrid.from_info`, and a reply that does not fit is
logged and left out, never let through to the page.
"""

from __future__ import annotations

import math
import queue
import re
import sys
import threading
import time
import traceback

import numpy as np
import orjson

from vrsim.common import ServiceError, VrsimError
from vrsim.services.bus import client, messages
from vrsim.services.bus.config import Keys, ZenohOptions, open_session
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.serving import guarded
from vrsim.services.bus.web import picture
from vrsim.services.bus.web.live import (
    FIELDS,
    HISTORY_POINTS,
    RECORD_FIELDS,
    Batch,
    LiveView,
    SectionGeometry,
    ViewGrid,
)

DECODERS = {"pose": messages.Pose, "shaft": messages.ShaftState, "rate": messages.RateSample}
RECORDS_PAGE = 20_000  # ticks per monitor/records query (the monitor's cap)
MAP_BATCH = messages.MAX_POINTS  # cell centres per map/rate query (the map service's limit: its reply
# must pass the router)
STATUS_EVERY_S = 1.0
REPORT_EVERY_S = 5.0  # a report rebuilds the run's arrays in the monitor: not more often than this
QUERY_TIMEOUT_S = 5.0
REPORT_TIMEOUT_S = 60.0
CATCHUP_WAIT_S = 1.0  # for the first live rate sample of a run joined late
CATCHUP_PATIENCE_S = 10.0  # for the monitor to store ticks it is behind on
FINAL_STATES = ("finished", "stopped", "failed")
RUN_ID = re.compile(r"^[A-Za-z0-9_.-]{1,200}$")  # what scenario control's run ids are made of


class Bridge:
    """Feeds ``view`` from the bus ``session`` (a viewer: it only subscribes and queries).

    One worker thread runs the slow jobs in order (the map, a run's field and path, a catch-up), so
    they never overlap; a poller thread asks for status each second and for the report while a page
    is open.
    """

    def __init__(self, session, keys: Keys, view: LiveView, report_every_s: float = REPORT_EVERY_S,
                 data: DataRoot | None = None):
        self.session, self.keys, self.view = session, keys, view
        self.data = data  # the run's scenario came over the bus: its files only under the data root
        self.report_every_s = report_every_s
        self.viewers = 0  # open /events streams (the report is only fetched for someone)
        self.map_png: bytes | None = None
        self.map_scale: dict | None = None
        self.map_version = 0
        self.map_rates: np.ndarray | None = None  # the rates map_png shows (kg/ha per view cell)
        self.jobs: queue.Queue = queue.Queue()
        self.stop = threading.Event()
        self.threads: list[threading.Thread] = []

    # ---------------------------------------------------------------- subscriptions
    def declare(self) -> list:
        handlers = {"pose": self.view.on_pose, "shaft": self.view.on_shaft, "rate": self.view.on_rate}
        return [self.session.declare_subscriber(getattr(self.keys, s),
                                                guarded("web", self._on_message(s, handlers[s])))
                for s in DECODERS]

    def _on_message(self, stream: str, handler):
        def on_sample(sample) -> None:
            batch = _decode(stream, sample.payload.to_bytes(), FIELDS[stream])
            new_run = handler(batch)
            if new_run is not None:
                self._follow(new_run, catch_up=batch.tick[0] > 0)

        return on_sample

    def _follow(self, run_id: str, catch_up: bool) -> None:
        """A run this view had not seen: its map (loaded before it started), field and path, and its
        past from the monitor when joined late."""
        if not RUN_ID.match(run_id):  # it goes into selectors: scenario control never makes such ids
            print(f"vrsim serve web: not following run {run_id[:80]!r}: not a run id", file=sys.stderr)
            return
        self.jobs.put(("map", run_id))  # a new run: its map may be a new one with the same info
        self.jobs.put(("run", run_id))
        if catch_up:
            self.jobs.put(("catchup", run_id))

    # ---------------------------------------------------------------- threads
    def start(self) -> None:
        self.jobs.put(("map", None))
        for target, name in ((self._work, "vrsim-web-jobs"), (self._poll, "vrsim-web-poll")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self.threads.append(thread)

    def close(self) -> None:
        self.stop.set()
        self.jobs.put(("stop", None))
        for thread in self.threads:
            thread.join(timeout=5.0)

    def _work(self) -> None:
        jobs = {"map": lambda run_id: self.refresh_map(new_run=run_id is not None), "run": self.load_run,
                "catchup": self.catch_up}
        while not self.stop.is_set():
            kind, arg = self.jobs.get()
            if kind == "stop":
                return
            try:
                jobs[kind](arg)
            except VrsimError as exc:
                print(f"vrsim serve web: {kind}: {exc}", file=sys.stderr, flush=True)
                if kind == "catchup":
                    self.view.set_catchup(arg, "failed", str(exc))
            except Exception:  # noqa: BLE001 - a bug: say so, keep serving what works
                print(f"vrsim serve web: internal error in the {kind} job:", file=sys.stderr, flush=True)
                traceback.print_exc(file=sys.stderr)

    def _poll(self) -> None:
        next_report, final_done = -math.inf, ""
        while True:
            try:
                status = self.status()
            except VrsimError as exc:
                status = {"state": "unknown", "run_id": "", "error": str(exc)}
            self.view.set_status(status)
            if self.view.map is None and self.jobs.empty():  # the map service was not up yet
                self.jobs.put(("map", None))
            run_id, state = status.get("run_id"), status.get("state")
            if isinstance(run_id, str) and run_id and self.view.adopt_run(run_id):
                self._follow(run_id, catch_up=True)
            due = state == "running" and time.monotonic() >= next_report
            final = state in FINAL_STATES and final_done != run_id
            if self.viewers > 0 and run_id == self.view.run_id and RUN_ID.match(run_id) and (due or final):
                asked = time.monotonic()
                try:
                    self.view.set_report(run_id, self.report(run_id))
                    final_done = run_id if final else final_done
                except VrsimError:
                    pass  # no complete ticks yet, or the monitor is down: the page keeps the last one
                # A report rebuilds the whole run in the monitor: at most a fifth of its time on them.
                took = time.monotonic() - asked
                next_report = asked + max(self.report_every_s, 5 * took)
            if self.stop.wait(STATUS_EVERY_S):
                return

    # ---------------------------------------------------------------- queries (the /api views too)
    def data_root(self) -> str | None:
        """Where uploads are kept (`services.bus.web.upload`): the data root, None without one."""
        return None if self.data is None else self.data.root

    def query(self, selector: str, timeout_s: float = QUERY_TIMEOUT_S):
        """One query's JSON reply (a `ServiceError` with the service's message otherwise)."""
        return client.request_json(self.session, selector, timeout_s=timeout_s)

    def status(self) -> dict:
        return _object(self.query(self.keys.scenario("status")), "scenario/status")

    def map_info(self) -> dict:
        return _object(self.query(self.keys.map_info), "map/info")

    def report(self, run_id: str | None = None) -> dict:
        selector = self.keys.report + (f"?run_id={run_id}" if run_id else "")
        return _object(self.query(selector, REPORT_TIMEOUT_S), "report")

    # ---------------------------------------------------------------- jobs
    def refresh_map(self, new_run: bool = False) -> None:
        """The prescription the map service serves now, sampled at the view grid's cell centres and
        rendered once to a PNG; skipped when its info is unchanged, unless for a ``new_run`` (whose
        map may hold other rates under the same info: then its rates are compared)."""
        info = self.map_info()
        grid = ViewGrid.from_info(info)
        current = self.view.map
        same = current is not None and current["info"] == info and current["grid"] == grid
        if same and not new_run:
            return
        rates = self._rates(grid)
        if same and self.map_rates is not None and np.array_equal(rates, self.map_rates, equal_nan=True):
            return
        colours = picture.scale(info)
        png = picture.render_png(rates, grid.rows, grid.cols, colours)
        self.map_rates = rates
        self.map_png, self.map_scale = png, colours
        self.map_version += 1
        if self.view.set_map(info, grid, self.map_version) and self.view.run_id:
            self.jobs.put(("catchup", self.view.run_id))  # the run so far, on the new grid

    def _rates(self, grid: ViewGrid) -> np.ndarray:
        x, y = grid.centres()
        out = np.full(grid.cells, np.nan)
        for a in range(0, grid.cells, MAP_BATCH):
            body = orjson.dumps({"x": x[a:a + MAP_BATCH].tolist(), "y": y[a:a + MAP_BATCH].tolist()})
            reply = orjson.loads(client.request(self.session, self.keys.map_rate, body, timeout_s=60.0))
            n = min(MAP_BATCH, grid.cells - a)
            if not isinstance(reply, list) or len(reply) != n:
                raise ServiceError(f"map/rate: expected {n} results, got {type(reply).__name__}")
            out[a:a + n] = [_rate(r) for r in reply]
        return out

    def load_run(self, run_id: str) -> None:
        """The run's scenario from the monitor, built as every service builds it: field boundary and
        coverage path for the page."""
        from vrsim.services.sim import scenario
        from vrsim.services.sim.world import build_world

        run = _object(self.query(f"{self.keys.monitor_run}?run_id={run_id}"), "monitor/run")
        text, source, base_dir = (run.get(k) for k in ("scenario_text", "source", "base_dir"))
        if not all(isinstance(v, str) for v in (text, source, base_dir)):
            raise ServiceError(f"monitor/run {run_id}: scenario_text, source and base_dir must be strings")
        parse = scenario.parse if self.data is None else self.data.scenario
        world = build_world(parse(text, source, base_dir))
        implement = world.scenario.implement
        # The live rates (kg/ha) shown in the map's own unit: one kg/ha in it (`maps.Grid.in_map_unit`).
        self.view.set_run_info(run_id, {"scenario": world.scenario.name, "clock": run.get("clock"),
                                        "field": _field_geometry(world), "rate_unit": world.grid.map_unit,
                                        "per_kg_ha": float(world.grid.in_map_unit(1.0))},
                               SectionGeometry(implement.section_widths, implement.section_offsets_m))

    def catch_up(self, run_id: str) -> None:
        """Paint the run's ticks from before the view saw it live, from the monitor's records."""
        deadline = time.monotonic() + CATCHUP_WAIT_S
        while True:
            current, first = self.view.run_state()
            if current != run_id:
                return
            if first["rate"] is not None or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        upto = first["rate"]
        if upto is None:  # nothing live (a finished run): everything the monitor has
            stored = _object(self.query(f"{self.keys.monitor_status}?run_id={run_id}"), "monitor/status")
            upto = stored.get("rate_records")
            if type(upto) is not int or upto < 0:
                raise ServiceError(f"monitor/status: rate_records {upto!r} is not a count")
        if upto == 0:
            return  # seen from its first tick: nothing to catch up
        self.view.set_catchup(run_id, "running")
        stride = max(1, math.ceil(upto / HISTORY_POINTS))
        start, idle_since = 0, time.monotonic()
        while start < upto and not self.stop.is_set():
            count = min(RECORDS_PAGE, upto - start)
            # The rate page first: the monitor gives fewer records than asked for where they hold each
            # of many drives' values; the pose and shaft pages then cover its ticks.
            pages = {"rate": self._records("rate", run_id, start, count)}
            if len(pages["rate"].tick):
                count = int(pages["rate"].tick[-1]) + 1 - start
            pages.update({s: self._records(s, run_id, start, count) for s in ("pose", "shaft")})
            self.view.backfill(pages["pose"], pages["shaft"], pages["rate"], stride)
            if len(pages["rate"].tick):
                start, idle_since = int(pages["rate"].tick[-1]) + 1, time.monotonic()
            elif time.monotonic() - idle_since > CATCHUP_PATIENCE_S:
                self.view.set_catchup(run_id, "failed", f"the monitor has no rate records from tick {start}")
                return
            else:
                time.sleep(0.5)  # the monitor is behind: it stores what is still on its way
        self.view.set_catchup(run_id, "done")

    def _records(self, stream: str, run_id: str, start: int, count: int) -> Batch:
        """Ticks [start, start + count) of ``run_id``'s ``stream`` the monitor has stored."""
        selector = (f"{self.keys.monitor_records}?run_id={run_id};stream={stream};"
                    f"from_tick={start};count={count}")
        raw = client.request(self.session, selector, timeout_s=60.0)
        if raw.strip() == b"[]":
            return Batch(run_id, {f: np.zeros(0) for f in RECORD_FIELDS[stream]})
        batch = _decode(stream, raw, RECORD_FIELDS[stream], max_len=count)
        if batch.run_id != run_id:
            return Batch(run_id, {k: v[:0] for k, v in batch.cols.items()})
        before = np.maximum.accumulate(np.concatenate([[start - 1], batch.tick[:-1]]))
        return batch.take((batch.tick > before) & (batch.tick < start + count))  # ascending, in range


class Operator:
    """The web service's only writes to the bus: start and stop a run through scenario control.

    It has a session of its own, opened with ``options``: logged in with the operator's credential from
    the state folder (``serve web --operator``; the web user, a viewer, cannot start or stop), or the
    same open bus as the viewer's with ``--insecure``.
    """

    PARAMS = ("clock", "speed", "ticks_per_message")
    _VALUE = re.compile(r"^[A-Za-z0-9._-]{1,32}$")
    _PATH = re.compile(r"^/[^;=?#&\s\x00-\x1f]{0,4000}$")  # an absolute path a selector carries as it is

    def __init__(self, options: ZenohOptions):
        self.keys = options.keys
        self.session = open_session(options)

    def check(self, verb: str, params: dict) -> None:
        """Refuse parameters other than `PARAMS`, and values that could break a selector."""
        for name, value in params.items():
            if name not in self.PARAMS or not self._VALUE.match(value):
                raise ServiceError(f"/api/{verb}: parameter {name}={value[:40]!r} is not one of "
                                   f"{', '.join(self.PARAMS)} with a plain value")

    def start_uploaded(self, kept, params: dict) -> dict:
        """``scenario/start`` of an upload (`services.bus.web.upload.Upload`): its text, named by its
        path, its relative paths resolved in its folder."""
        where = {"source": kept.source, "base_dir": kept.base_dir}
        for name, path in where.items():
            if not self._PATH.match(path):
                raise ServiceError(f"/api/start: the upload's {name} {path[:200]!r} holds characters a "
                                   "selector cannot carry (';', '=', '?', '#', '&', spaces): give the "
                                   "services a --data-root without them")
        return self.request("start", kept.text.encode(), params, where)

    def request(self, verb: str, body: bytes | None = None, params: dict | None = None,
                where: dict | None = None) -> dict:
        """``<prefix>/scenario/<verb>`` (start or stop) with ``body`` and selector ``params`` (and the
        ``source`` and ``base_dir`` of an upload, ``where``): the one function through which the web
        service writes to the bus."""
        params = params or {}
        self.check(verb, params)
        params = {**params, **(where or {})}
        selector = self.keys.scenario(verb) + ("?" + ";".join(f"{k}={v}" for k, v in params.items())
                                               if params else "")
        return _object(client.request_json(self.session, selector, body or None, timeout_s=120.0,
                                           what=f"scenario/{verb}"), f"scenario/{verb}")

    def close(self) -> None:
        self.session.close()


def _decode(stream: str, payload: bytes, fields: tuple[str, ...], max_len: int = 100_000) -> Batch:
    """One message of ``stream`` as a `Batch` of ``fields``, checked by the stream's schema and
    refused when its records are of several runs (a publisher sends one run's ticks per message)."""
    cols, last = messages.decode_columns(DECODERS[stream], payload, ("run_id", *fields), max_len)
    run_ids = cols.pop("run_id")
    if run_ids.count(run_ids[0]) != len(run_ids):
        raise ServiceError(f"{stream}: a message with records of several runs ({run_ids[0]!r}, ...)")
    return Batch(run_ids[0], cols, last.to_dict())


def _field_geometry(world) -> dict:
    """Field boundary rings and coverage path in the field's CRS, cm precision, the path simplified to
    10 cm (a page draws it, nobody measures on it)."""
    from shapely.geometry import LineString

    poly = world.field.polygon
    rings = [poly.exterior, *poly.interiors]
    path = LineString(world.path.xy).simplify(0.1)
    return {"crs": world.field.crs.to_string(),
            "boundary": [np.round(np.asarray(r.coords), 2).tolist() for r in rings],
            "path": np.round(np.asarray(path.coords), 2).tolist()}


def _object(doc, what: str) -> dict:
    if not isinstance(doc, dict):
        raise ServiceError(f"{what}: expected a JSON object, got {type(doc).__name__}")
    return doc


def _rate(result) -> float:
    value = result.get("rate_kg_ha") if isinstance(result, dict) else None
    return float(value) if type(value) in (int, float) else math.nan
