"""The monitor service: records every pose, shaft and rate sample in SQLite and reports applied
versus prescribed (``vrsim serve monitor``).

Each message is committed to a local SQLite database (WAL) before the next is read: a monitor killed
and restarted on the same ``--db`` has lost nothing it had received. ``<prefix>/<machine>/report``
rebuilds the run from the database (`recorded_run`, also ``vrsim report --db``'s) and accounts for it as
``vrsim run`` does (`services.sim.run.accounted`): the keys of ``vrsim run --json`` over every tick
stored, plus ``missing_ticks``, ``complete`` and ``end_reason`` (`_completeness`: complete only for a
finished run, as scenario control announced on ``monitor/end``, with every tick stored); reports are
answered again while they hold (`services.bus.reads`). A record is stored only for a run announced by
``monitor/load`` (only scenario control may) and once per tick: a second one is ignored.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import time

import numpy as np

from vrsim.common import ServiceError
from vrsim.common.section_masks import sections_from_masks
from vrsim.services.bus import messages
from vrsim.services.bus import records as sql
from vrsim.services.bus.config import ServiceConfig
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.reads import (
    MAX_CACHED_REPORTS,
    REPORT_BURST,
    REPORT_RATE_PER_S,
    CachedReport,
    RateLimit,
)
from vrsim.services.bus.serving import Later, Params, guarded, payload_bytes, run_service, serve
from vrsim.services.outputs.encode import dumps

NAN = float("nan")
STREAMS = {"pose": messages.Pose, "shaft": messages.ShaftState, "rate": messages.RateSample}
MAX_RECORDS = 20_000  # per monitor/records reply (about 5 MB of JSON)
MAX_VALUES = 11 * MAX_RECORDS  # ... and values per reply (each drive's counts): at most ~7 MB of JSON
SCHEMA_VERSION = 5  # 2: measured speed in pose, section width and offset in rate; 3: path distance in pose,
#                     section mask in rate; 4: each drive's target, rate and product; 5: spinner's steps on
# A run's announced end (`messages.RunEnd`), NULL until scenario control announces it.
_END_COLUMNS = (("end_reason", "TEXT"), ("end_ticks", "INTEGER"), ("end_sim_time_s", "REAL"),
               ("end_error", "TEXT"), ("ended_unix", "REAL"))
MEASURED = ("measured_x_m", "measured_y_m", "measured_speed_m_s")  # what the controller read, per tick


class MonitorStore:
    """The monitor's SQLite database: runs, and one table per stream keyed by (run_id, tick).

    Parameters
    ----------
    path : str
        Database file; created with its folder if missing, the file 0600 and a new folder 0700 (it holds
        every pose and every scenario's text: `private_db`).
    """

    def __init__(self, path: str):
        self.path = path
        _private_db(path)
        try:
            self.db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            self.db.execute("PRAGMA journal_mode=WAL")
            # NORMAL in WAL mode: a committed transaction survives the process being killed.
            self.db.execute("PRAGMA synchronous=NORMAL")
            self._create()
        except sqlite3.Error as exc:
            raise ServiceError(f"--db {path}: cannot open the monitor database: {exc}") from None
        self.lock = threading.Lock()  # subscriber threads and the report query share the connection
        self.stored: dict[str, int] = {}  # run_id -> records stored by this process (a report's cache key)
        self._reader = None  # the reports' own connection (WAL: reading does not hold up ingest)
        self.read_lock = threading.Lock()

    def _create(self) -> None:
        db = self.db
        db.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
        db.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
        found = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0]
        if found != str(SCHEMA_VERSION):
            raise ServiceError(f"--db {self.path}: written by another vrsim version (schema {found}, "
                               f"this one writes {SCHEMA_VERSION}); give a new --db file")
        db.execute("CREATE TABLE IF NOT EXISTS runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, "
                   "run_id TEXT UNIQUE, scenario_text TEXT, source TEXT, base_dir TEXT, clock TEXT, "
                   "started_unix REAL, last_unix REAL)")
        have = {row[1] for row in db.execute("PRAGMA table_info(runs)")}
        for name, kind in _END_COLUMNS:  # added to an older file in place: it opens as it was, no end
            if name not in have:
                db.execute(f"ALTER TABLE runs ADD COLUMN {name} {kind}")
        for table, cls in STREAMS.items():
            cols = ", ".join(sql.sql_types(cls))
            db.execute(f"CREATE TABLE IF NOT EXISTS {table} (run_id TEXT, tick INTEGER, {cols}, "
                       "PRIMARY KEY (run_id, tick)) WITHOUT ROWID")

    def add_run(self, start: messages.RunStart) -> None:
        """Announce a run (a second announcement of the same run id changes nothing)."""
        with self.lock:
            self.db.execute("INSERT OR IGNORE INTO runs (run_id, scenario_text, source, base_dir, clock, "
                            "started_unix, last_unix) VALUES (?, ?, ?, ?, ?, ?, ?)",
                            (start.run_id, start.scenario_text, start.source, start.base_dir, start.clock,
                             time.time(), time.time()))

    def run_ids(self) -> set[str]:
        """Every run announced so far."""
        with self.lock:
            return {row[0] for row in self.db.execute("SELECT run_id FROM runs")}

    def add(self, table: str, records: list) -> None:
        """Store one message's records in one transaction; a tick already stored keeps its first record."""
        cols = sql.columns(STREAMS[table])
        rows = [(r.run_id, r.tick, *(sql.stored(getattr(r, c)) for c in cols)) for r in records]
        marks = ", ".join("?" * (len(cols) + 2))
        with self.lock:
            self.db.execute("BEGIN")
            try:
                insert = f"INSERT OR IGNORE INTO {table} VALUES ({marks})"
                added = self.db.executemany(insert, rows).rowcount
                if added > 0:  # ticks already stored change nothing
                    self.stored[records[0].run_id] = self.stored.get(records[0].run_id, 0) + added
                    self.db.execute("UPDATE runs SET last_unix = ? WHERE run_id = ?",
                                    (time.time(), records[0].run_id))
                self.db.execute("COMMIT")
            except BaseException:
                self.db.execute("ROLLBACK")
                raise

    def run(self, run_id: str | None = None) -> dict:
        """The run ``run_id`` (default: the latest started) as a dict of its `runs` row."""
        query = "SELECT run_id, scenario_text, source, base_dir, clock, started_unix, last_unix FROM runs "
        with self.lock:
            if run_id is None:
                row = self.db.execute(query + "ORDER BY seq DESC LIMIT 1").fetchone()
            else:
                row = self.db.execute(query + "WHERE run_id = ?", (run_id,)).fetchone()
        if row is None:
            what = "no run recorded yet" if run_id is None else f"no run {run_id!r}"
            raise ServiceError(f"monitor: {what} in {self.path}")
        return dict(zip(("run_id", "scenario_text", "source", "base_dir", "clock", "started_unix",
                         "last_unix"), row, strict=True))

    def set_end(self, end: messages.RunEnd) -> dict:
        """Store a run's announced end; the first announcement stays (a second changes nothing).
        Returns the end stored (`end`)."""
        with self.lock:
            self.db.execute("UPDATE runs SET end_reason = ?, end_ticks = ?, end_sim_time_s = ?, "
                            "end_error = ?, ended_unix = ? WHERE run_id = ? AND end_reason IS NULL",
                            (end.reason, end.ticks, end.sim_time_s, end.error, time.time(), end.run_id))
        return self.end(end.run_id)

    def end(self, run_id: str) -> dict | None:
        """The run's announced end as ``{"reason", "ticks", "sim_time_s", "error"}``, None if none was."""
        with self.lock:
            row = self.db.execute("SELECT end_reason, end_ticks, end_sim_time_s, end_error FROM runs "
                                  "WHERE run_id = ?", (run_id,)).fetchone()
        if row is None or row[0] is None:
            return None
        return dict(zip(("reason", "ticks", "sim_time_s", "error"), row, strict=True))

    def counts(self, run_id: str) -> dict[str, int]:
        """Records per stream, and ``complete``: ticks with all three stored."""
        with self.lock:
            out = {t: self.db.execute(f"SELECT COUNT(*) FROM {t} WHERE run_id = ?", (run_id,)).fetchone()[0]
                   for t in STREAMS}
            out["complete"] = self.db.execute(
                "SELECT COUNT(*) FROM pose JOIN shaft USING (run_id, tick) JOIN rate USING (run_id, tick) "
                "WHERE run_id = ?", (run_id,)).fetchone()[0]
        return out

    def live_error(self, run_id: str) -> tuple[int, float, float]:
        """(samples, mean |applied - prescribed|, mean applied - prescribed), kg/ha, over the rate
        samples with the implement on and both rates known: the per-tick error at the landing point
        predicted when metering, as it streams in (the report's figures are over the landed map)."""
        with self.lock:
            n, mae, bias = self.db.execute(
                "SELECT COUNT(*), AVG(ABS(applied_kg_ha - prescribed_kg_ha)), "
                "AVG(applied_kg_ha - prescribed_kg_ha) FROM rate WHERE run_id = ? AND implement_on "
                "AND applied_kg_ha IS NOT NULL AND prescribed_kg_ha IS NOT NULL", (run_id,)).fetchone()
        return n, NAN if mae is None else mae, NAN if bias is None else bias

    def records(self, table: str, run_id: str, from_tick: int, count: int) -> list:
        """The stored messages of one stream with ticks in [from_tick, from_tick + count), in tick order
        (what was published, for a client that joins a run late); fewer where they would hold more than
        `MAX_VALUES` values (a machine of many drives)."""
        cls = STREAMS[table]
        cols = sql.columns(cls)
        with self.lock:
            rows = self.db.execute(f"SELECT tick, {', '.join(cols)} FROM {table} WHERE run_id = ? "
                                   "AND tick >= ? AND tick < ? ORDER BY tick",
                                   (run_id, from_tick, from_tick + count)).fetchall()
        kinds = [kind for name, kind, _ in cls._spec if name in cols]
        # SQLite hands back REAL columns as floats (NaN stored as NULL): give each field its type back.
        found = [cls(run_id, tick, *(sql.field_value(v, kind) for v, kind in zip(vals, kinds, strict=True)))
                 for tick, *vals in rows]
        return sql.fitting(found, cls, MAX_VALUES)

    def reader(self) -> sqlite3.Connection:
        """The connection reports read through (made on first use): a report's whole-run query runs
        beside the ingest's writes instead of holding their lock for a second."""
        if self._reader is None:
            self._reader = sqlite3.connect(self.path, check_same_thread=False)
        return self._reader

    def close(self) -> None:
        for conn in (self.db, self._reader):
            if conn is not None:
                conn.close()

    def arrays(self, run_id: str, sections: int, drives: int, side_steps: int = 1) -> tuple[dict, dict]:
        """Track and control arrays (the shapes `services.sim.run.accounted` takes; the track also holds
        the `MEASURED` arrays) over every complete tick (pose, shaft and rate all stored), in tick order;
        ``track["tick"]`` says which ticks they are (`missing_ticks` the gaps); `sections`, `drives`,
        `side_steps`: the implement's and its machine's (masks; ``drive_*``; ``side_steps_on``)."""
        pose_cols = ("time_s", "x_m", "y_m", "heading_rad", "speed_m_s", "implement_on", *MEASURED)
        shaft_cols = ("target_shaft_rpm", "shaft_rpm", "shaft_rev", "current_a")
        rate_cols = ("landing_x_m", "landing_y_m", "prescribed_kg_ha", "metered_kg", "width_on_m")
        per_drive = (("shaft", "drive_target_rpm"), ("rate", "drive_rate_kg_ha"), ("rate", "drive_kg"))
        select = ", ".join([f"p.{c}" for c in pose_cols] + [f"s.{c}" for c in shaft_cols]
                           + [f"r.{c}" for c in rate_cols] + [f"{t[0]}.{c}" for t, c in per_drive])  # s., r.
        with self.read_lock:
            rows = self.reader().execute(
                f"SELECT p.tick, {select}, r.side_steps_on, r.section_mask FROM pose p JOIN shaft s "
                "USING (run_id, tick) JOIN rate r USING (run_id, tick) WHERE p.run_id = ? ORDER BY p.tick",
                (run_id,)).fetchall()
        masks = [row[-1] for row in rows]
        table = np.array([row[:-5] for row in rows], dtype=np.float64).reshape(
            len(rows), 1 + len(pose_cols) + len(shaft_cols) + len(rate_cols))
        cols = table[:, 1:]
        track = {c: cols[:, i] for i, c in enumerate(pose_cols)}
        track["implement_on"] = track["implement_on"].astype(bool)
        track["tick"] = table[:, 0].astype(np.int64)
        control = {c: cols[:, len(pose_cols) + i] for i, c in enumerate(shaft_cols + rate_cols)}
        ticks, stream = track["tick"], "rate"
        try:
            control["sections_on"] = sections_from_masks(masks, sections)
            control.update(sql.steps_values([row[-2] for row in rows], side_steps, ticks))
            for col, (name, key) in enumerate(per_drive, start=-5):
                stream, control[key] = name, sql.drive_values([row[col] for row in rows], drives, ticks, key)
        except ValueError as exc:
            raise ServiceError(f"{run_id}: {stream} records: {exc}") from None
        return track, control


def _missing_ticks(ticks: np.ndarray) -> list[list[int]]:
    """The ticks in 0..max(ticks) that ``ticks`` (sorted, unique) lacks, as [first, last] ranges."""
    ticks = np.asarray(ticks, dtype=np.int64)
    if len(ticks) == 0:
        return []
    before = np.concatenate(([-1], ticks[:-1]))
    gaps = np.flatnonzero(ticks - before > 1)
    return [[int(before[i]) + 1, int(ticks[i]) - 1] for i in gaps]


class _MonitorService:
    """Handlers of the monitor: ingest the streams, report, status, load a run."""

    def __init__(self, store: MonitorStore, data: DataRoot):
        self.store = store
        self.data = data
        self.worlds: dict[str, object] = {}  # run_id -> World, rebuilt once per run from its text
        self.report_lock = threading.Lock()
        # run_id -> its last report: every run's (a few kB each), so asking for runs in turn makes each once
        self.reports: dict[str, CachedReport] = {}
        self.limit = RateLimit(REPORT_RATE_PER_S, REPORT_BURST)
        self.runs = store.run_ids()  # the runs announced by monitor/load: records of others are dropped

    def ingest(self, table: str):
        cls = STREAMS[table]

        def on_sample(sample) -> None:
            data = payload_bytes(sample.payload, str(sample.key_expr), messages.MAX_MESSAGE_BYTES)
            records = messages.decode_batch(cls, data)
            known = [r for r in records if r.run_id in self.runs]
            if known:
                self.store.add(table, known)
            if len(known) < len(records):
                unknown = next(r.run_id for r in records if r.run_id not in self.runs)
                raise ServiceError(f"{len(records) - len(known)} record(s) of run {unknown!r}, which no "
                                   "monitor/load announced")

        return on_sample

    def end(self, params: Params, payload: bytes | None) -> bytes:
        """Store a run's announced end (scenario control sends it; the access rules let no viewer)."""
        params.only()
        end = messages.RunEnd.from_json(payload)
        if end.run_id not in self.runs:
            raise ServiceError(f"{params.key}: no run {end.run_id!r} was announced by monitor/load")
        stored = self.store.set_end(end)
        return dumps({"ended": True, "run_id": end.run_id, **stored})

    def load(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        start = messages.RunStart.from_json(payload)
        self.store.add_run(start)
        self.runs.add(start.run_id)
        return dumps({"loaded": True, "run_id": start.run_id})

    def status(self, params: Params, payload: bytes | None) -> bytes:
        params.only("run_id")
        run = self.store.run(params.text("run_id"))
        counts = self.store.counts(run["run_id"])
        samples, mae, bias = self.store.live_error(run["run_id"])
        return messages.MonitorStatus(run["run_id"], counts["pose"], counts["shaft"], counts["rate"],
                                      counts["complete"], samples, mae, bias, self.store.path).to_json()

    def run_info(self, params: Params, payload: bytes | None) -> bytes:
        params.only("run_id")
        return dumps(self.store.run(params.text("run_id")))

    def records(self, params: Params, payload: bytes | None) -> bytes:
        params.only("run_id", "stream", "from_tick", "count")
        stream = params.text("stream")
        if stream is None:
            raise ServiceError(f"{params.key}: missing parameter stream (one of {', '.join(STREAMS)})")
        if stream not in STREAMS:
            raise ServiceError(f"{params.key}: parameter stream={stream!r} must be one of "
                               f"{', '.join(STREAMS)}")
        run = self.store.run(params.text("run_id"))
        from_tick = params.integer("from_tick", 0, 2**62, 0)
        count = params.integer("count", 1, MAX_RECORDS, MAX_RECORDS)
        return messages.encode_batch(self.store.records(stream, run["run_id"], from_tick, count))

    def report(self, params: Params, payload: bytes | None) -> bytes | Later:
        params.only("run_id")
        refused = self.limit.admit(params.key)
        if refused is not None:
            return refused
        run_id = self.store.run(params.text("run_id"))["run_id"]
        key = (self.store.stored.get(run_id, 0), self.store.end(run_id))
        cached = self.reports.get(run_id)
        if cached is not None and cached.fresh(key):
            return cached.body
        # One report at a time (each rebuilds whole-run arrays): meanwhile the others get the last one.
        if not self.report_lock.acquire(blocking=cached is None):
            return cached.body
        try:
            return self._recompute(run_id, key)
        finally:
            self.report_lock.release()

    def _recompute(self, run_id: str, key: tuple) -> bytes:
        from vrsim.services.outputs.summary import summary_json  # what `vrsim run --json` prints with
        from vrsim.services.sim.as_run import with_settings

        cached = self.reports.get(run_id)
        if cached is not None and cached.fresh(key):  # made while this query waited for the lock
            return cached.body
        t0 = time.monotonic()
        body = summary_json(with_settings(self._report(run_id))).encode()
        self.reports.pop(run_id, None)
        while len(self.reports) >= MAX_CACHED_REPORTS:  # the oldest made first out
            self.reports.pop(next(iter(self.reports)))
        self.reports[run_id] = CachedReport(key, body, time.monotonic(), time.monotonic() - t0)
        return body

    def _report(self, run_id: str | None):
        return recorded_run(self.store, self.store.run(run_id), self._world)

    def _world(self, run: dict):
        world = self.worlds.get(run["run_id"])
        if world is None:
            world = _run_world(run, self.data)
            self.worlds = {run["run_id"]: world}  # keep one: worlds hold whole grids
        return world

    def machine_handlers(self) -> dict:
        return {"report": self.report}

    def handlers(self) -> dict:
        return {"load": self.load, "end": self.end, "status": self.status, "run": self.run_info,
                "records": self.records}


def _run_world(run: dict, data: DataRoot | None = None):
    """The world of a recorded run, rebuilt from the scenario text the run was started with (its files
    confined to `data`'s root when given: the monitor's scenarios came over the bus; ``vrsim report``
    reads local files as ``vrsim run`` does)."""
    from vrsim.services.sim import scenario
    from vrsim.services.sim.world import build_world

    parse = scenario.parse if data is None else data.scenario
    return build_world(parse(run["scenario_text"], run["source"], run["base_dir"]))


def recorded_run(store: MonitorStore, run: dict, world_of=_run_world):
    """A services run as a `services.sim.run.RunResult`, rebuilt from its records over the complete
    ticks with `services.sim.run.accounted`, the function ``vrsim run`` uses: the monitor's report is its
    summary, and ``vrsim report`` writes its files with ``vrsim run``'s writers.

    Parameters
    ----------
    store : MonitorStore
    run : dict
        The run's row (`MonitorStore.run`).
    world_of : callable
        ``world_of(run) -> World`` (default `_run_world`; the monitor keeps the last one).
    """
    from vrsim.services.sim.accounting import StageTimer
    from vrsim.services.sim.machines import machine_for
    from vrsim.services.sim.run import accounted

    t0 = time.perf_counter()
    world = world_of(run)  # first: the records' section masks and drives need the implement's
    t1 = time.perf_counter()
    machine = machine_for(world.scenario.implement)
    track, control = store.arrays(run["run_id"], machine.implement.sections, machine.drives,
                                  machine.side_steps)
    n = len(track["time_s"])
    if n < 2:
        raise ServiceError(f"{run['run_id']}: {n} complete tick(s) recorded so far; a report needs 2")
    measured = tuple(track.pop(key) for key in MEASURED)
    # The wall time is the services run's, by its records' clock, not this report's.
    timer = StageTimer({"build_s": t1 - t0, "read_s": time.perf_counter() - t1},
                       wall_time_s=max(run["last_unix"] - run["started_unix"], 1e-9))
    result = accounted(world, track, measured, control, timer, run["started_unix"])
    summary = result.summary
    summary["outputs_wall_s"] = 0.0
    summary["out_dir"] = store.path  # where the records are (the monitor writes no other output)
    summary.update(_completeness(track["tick"], store.end(run["run_id"])))
    return result


def _completeness(ticks: np.ndarray, end: dict | None) -> dict:
    """``missing_ticks``, ``complete`` and ``end_reason`` of a run whose stored complete ticks are
    ``ticks`` (sorted) and whose announced end is ``end`` (`MonitorStore.end`; None: none announced).

    The missing ticks are the gaps and, when the end is known, the unstored tail up to its last tick;
    ``complete`` only for a finished run with every tick stored. ``end_reason`` is the end's reason, or
    ``unknown`` (no end announced: the run is live, or the monitor or scenario control was down when
    it ended; the ticks after the last stored one cannot be named then).
    """
    gaps = _missing_ticks(ticks)
    stored_to = int(ticks[-1]) + 1 if len(ticks) else 0
    if end is not None and end["ticks"] > stored_to:
        gaps.append([stored_to, int(end["ticks"]) - 1])
    reason = "unknown" if end is None else end["reason"]
    return {"missing_ticks": gaps, "complete": reason == "finished" and not gaps, "end_reason": reason}


def _default_db(options) -> str:
    """``runs/monitor/<prefix>-<machine>.sqlite``: one database per prefix and machine, in a folder of
    the monitor's own (made 0700 by `private_db`)."""
    return os.path.join(DEFAULT_DB_FOLDER, f"{options.prefix.replace('/', '_')}-{options.machine}.sqlite")


DEFAULT_DB_FOLDER = os.path.join("runs", "monitor")
_DB_FILES = ("", "-wal", "-shm", "-journal")  # SQLite's files of a database (it gives them its mode)


def _private_db(path: str) -> None:
    """Make ``path`` a database file only its owner reads: its folder created 0700 if missing (the
    default folder tightened to 0700 if it is not), the file created 0600 before SQLite opens it, and
    an older database's files (0644 before) tightened to 0600 where they can be. A symlink is refused."""
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        if folder == os.path.abspath(DEFAULT_DB_FOLDER):
            os.chmod(folder, 0o700)
    except OSError as exc:
        raise ServiceError(f"--db {path}: cannot create its folder {folder}: {exc.strerror}") from None
    try:
        if not os.path.lexists(path):
            flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
            os.close(os.open(path, flags, 0o600))
    except OSError as exc:
        raise ServiceError(f"--db {path}: cannot create it as a private file: {exc.strerror}") from None
    if os.path.islink(path):
        raise ServiceError(f"--db {path}: is a symlink; give the database file itself")
    for name in (path + suffix for suffix in _DB_FILES if os.path.isfile(path + suffix)):
        st = os.stat(name)
        if st.st_mode & 0o077 and st.st_uid == os.getuid():
            try:
                os.chmod(name, 0o600)
            except OSError:  # a database on a read-only mount, read by `vrsim report`: as it is
                pass


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Serve the monitor on ``config.db`` (default `default_db`) until SIGINT/SIGTERM (or ``stop``)."""
    import vrsim.services.sim.run  # noqa: F401 - seconds of imports (scipy, shapely...): not in the first report

    store = MonitorStore(config.db or _default_db(config.zenoh))
    svc = _MonitorService(store, DataRoot.of(config))
    keys = config.zenoh.keys
    base = f"{keys.prefix}/{keys.machine}/"

    def declare(session):
        subs = [session.declare_subscriber(getattr(keys, t), guarded("monitor", svc.ingest(t)))
                for t in STREAMS]
        return [*subs,
                serve(session, keys.machine_ns, svc.machine_handlers(), base, "monitor"),
                serve(session, keys.monitor_ns, svc.handlers(), base + "monitor/", "monitor")]

    try:
        run_service("monitor", config.zenoh, declare, stop=stop)
    finally:
        store.close()
    return 0
