"""The messages of the vrsim Zenoh API: one dataclass per message, JSON field names with units.

Every message is a flat JSON object whose keys are the dataclass's fields. The per-tick streams
(`Pose`, `ShaftState`, `RateSample`) travel as a JSON array of such objects: one element per tick
(real-time mode sends one tick per message, lockstep mode several, see docs/api.md). Floats that are
NaN (e.g. the rate outside the map) are JSON ``null``; decoding turns ``null`` back into NaN, except for
fields typed ``X | None``, which stay None. A field whose default is None is optional: left out of the
JSON while it is None, None when a message leaves it out (``RateSample.side_steps_on``).

Decoding checks every key and type and raises `common.ServiceError` naming the message, the field and
the offending value, so a malformed message gets an error reply, never a traceback.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import orjson

from vrsim.common import ServiceError
from vrsim.services.bus.fields import KINDS, Floats, Steps, check, short
from vrsim.services.outputs.encode import dumps

# The API a Zenoh client in Python uses: the messages, their codecs and the limits they check.
__all__ = [
    "Message", "Pose", "ShaftState", "RateSample", "MapRate", "RunStart", "StepAck", "RunStatus",
    "MonitorStatus",
    "encode_batch", "decode_batch", "decode_columns", "decode_points", "encode_rates",
    "MAX_MESSAGE_BYTES", "MAX_BATCH_RECORDS", "MAX_POINTS", "MAX_POINTS_BYTES", "MAX_RATES_REPLY_BYTES",
    "max_points", "CLOCKS", "SPEED_RANGE", "TICKS_PER_MESSAGE_RANGE", "NAN",
]

NAN = math.nan


class Message:
    """Mixin: to_dict / to_json / from_dict / from_json for a flat dataclass."""

    _spec: tuple  # ((name, kind, nullable), ...) built by `_message`
    _names: frozenset
    _optional: frozenset  # the fields left out while None (default None)

    def to_dict(self) -> dict:
        """The fields, in order, but an optional one that is None (NaN stays NaN: `to_json` writes it
        as null)."""
        doc = dict(self.__dict__)
        for name in self._optional:
            if doc[name] is None:
                del doc[name]
        return doc

    def to_json(self) -> bytes:
        return dumps(self.to_dict() if self._optional else self)

    @classmethod
    def _fits(cls, keys) -> bool:
        """Whether an object's ``keys`` are the fields', an optional one perhaps left out."""
        names = cls._names
        return keys == names or (bool(cls._optional) and names - cls._optional <= keys <= names)

    @classmethod
    def from_dict(cls, doc, where: str = ""):
        if not isinstance(doc, dict) or not cls._fits(doc.keys()):
            cls._refuse_shape(doc, where or cls.__name__)
        values = {}
        for name, kind, nullable in cls._spec:
            value = doc.get(name)  # an optional field left out: None
            # Fast path: exactly the declared type (type(), so True is not an int).
            if type(value) is not kind:
                value = check(value, kind, nullable, where or cls.__name__, name)
            values[name] = value
        return cls(**values)

    @classmethod
    def _refuse_shape(cls, doc, where: str):
        if not isinstance(doc, dict):
            raise ServiceError(f"{where}: expected a JSON object, got {short(doc)}")
        missing = [k for k, _, _ in cls._spec if k not in doc and k not in cls._optional]
        if missing:
            raise ServiceError(f"{where}: missing field {missing[0]!r}")
        unknown = sorted(set(doc) - cls._names)
        raise ServiceError(f"{where}: unknown field {unknown[0]!r} "
                           f"(fields: {', '.join(k for k, _, _ in cls._spec)})")

    @classmethod
    def from_json(cls, data: bytes | str | None):
        return cls.from_dict(_loads(data, cls.__name__))


MAX_MESSAGE_BYTES = 8 * 1024 * 1024  # one message or batch of records (a pose batch is ~0.3 MB)
MAX_BATCH_RECORDS = 10_000  # records in one batch (ticks_per_message is at most 1000)
# A map/rate body: two arrays of full-precision coordinates take ~40 bytes a point. The cap keeps the
# parsed lists (a float is 32 bytes, and "1.0," packs one into 4 bytes) under ~0.4 GB.
MAX_POINTS_BYTES = 48 * 1024 * 1024
# A map/rate batch reply travels through the router, which drops any message over 65 MiB
# (`security.MAX_BODY_BYTES` plus its overhead) without a word to either side: so the reply is kept
# to 48 MiB. One point's `MapRate` object takes at most `_RATE_POINT_BYTES` plus its unit's bytes:
# the keys, quotes and punctuation (67 bytes with the comma between objects), two floats of at most
# 24 characters (orjson's shortest round trip, "-2.2250738585072014e-308"), a row and a column of at
# most 10 digits.
MAX_RATES_REPLY_BYTES = 48 * 1024 * 1024
_RATE_POINT_BYTES = 67 + 2 * 24 + 2 * 10
# Points in one map/rate query: with any unit of up to 64 ASCII characters (`maps.units.MAX_UNIT_CHARS`;
# vrsim's own names take at most 8) a reply is at most 250,000 x 199 bytes, 47.4 MiB. (A typical kg/ha
# reply is ~115 bytes a point: 29 MB.)
MAX_POINTS = 250_000


def max_points(unit: str) -> int:
    """The most points one map/rate query may ask of a map in ``unit``: `MAX_POINTS`, fewer only for
    a unit whose JSON text is so long (non-ASCII or escaped characters) that the reply would pass
    `MAX_RATES_REPLY_BYTES`."""
    per_point = _RATE_POINT_BYTES + len(dumps(unit)) - 2  # the quotes are in _RATE_POINT_BYTES
    return min(MAX_POINTS, MAX_RATES_REPLY_BYTES // per_point)


def _loads(data, what: str, max_bytes: int = MAX_MESSAGE_BYTES, most: tuple | None = None):
    """Parse JSON bytes, refusing an empty or oversize payload before parsing, and with ``most`` =
    (token, limit, reason) one that holds ``token`` more than ``limit`` times: counted in C (~10 ms for
    50 MB), since parsing builds a Python object per value, 10-30 times the bytes."""
    if data is None or len(data) == 0:
        raise ServiceError(f"{what}: empty payload, expected JSON")
    if len(data) > max_bytes:
        raise ServiceError(f"{what}: a payload of {len(data):,} bytes is over the {max_bytes:,}-byte limit")
    if most is not None and len(data) > most[1] and data.count(most[0]) > most[1]:
        raise ServiceError(f"{what}: {most[2]}, refused before parsing")
    try:
        return orjson.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:  # orjson.JSONDecodeError is a ValueError
        raise ServiceError(f"{what}: payload is not valid JSON ({exc})") from None


def _message(cls):
    """Class decorator: a dataclass with the `Message` codec, its field kinds read from annotations."""
    cls = dataclass(cls)
    spec = []
    for f in dataclasses.fields(cls):
        if f.type not in KINDS:
            raise TypeError(f"{cls.__name__}.{f.name}: unsupported field type {f.type!r}")
        spec.append((f.name, *KINDS[f.type]))
    cls._spec = tuple(spec)
    cls._names = frozenset(name for name, _, _ in spec)
    cls._optional = frozenset(f.name for f in dataclasses.fields(cls) if f.default is None)
    return cls


def encode_batch(records) -> bytes:
    """A JSON array of messages (the per-tick streams)."""
    return dumps([r.to_dict() if r._optional else r for r in records])


def decode_batch(cls, data, max_len: int = MAX_BATCH_RECORDS, max_bytes: int = MAX_MESSAGE_BYTES) -> list:
    """Decode a JSON array of ``cls`` messages (a single object is accepted as a batch of one); at most
    ``max_bytes`` of JSON (checked before parsing) and ``max_len`` records."""
    doc = _loads(data, f"{cls.__name__} batch", max_bytes, (b"{", max_len, f"more than {max_len:,} records"))
    if isinstance(doc, dict):
        doc = [doc]
    if not isinstance(doc, list) or not doc:
        raise ServiceError(f"{cls.__name__} batch: expected a non-empty JSON array of objects, "
                           f"got {short(doc)}")
    if len(doc) > max_len:
        raise ServiceError(f"{cls.__name__} batch: {len(doc)} records, at most {max_len} per message")
    return [cls.from_dict(d, f"{cls.__name__}[{i}]") for i, d in enumerate(doc)]


def decode_columns(cls, data, fields: tuple[str, ...], max_len: int = 100_000) -> tuple[dict, object]:
    """A JSON array of ``cls`` messages as columns: the same checks as `decode_batch` (every record
    has exactly the fields, each requested field has its type), several times faster for a reader that
    needs a few fields of every record (the web service keeps up with a lockstep run this way).

    Returns
    -------
    (columns, last) : (dict, cls)
        ``{field: ndarray}`` for ``fields`` (float fields: NaN for null; str fields: a list), and the
        last record decoded whole. Anything that does not fit raises `decode_batch`'s own error.
    """
    doc = _loads(data, f"{cls.__name__} batch")
    doc = [doc] if isinstance(doc, dict) else doc
    names = cls._names
    if not (isinstance(doc, list) and 0 < len(doc) <= max_len
            and all(type(d) is dict and (d.keys() == names or cls._fits(d.keys())) for d in doc)):
        _refuse(cls, data, max_len)
    kinds = {name: (kind, nullable) for name, kind, nullable in cls._spec}
    columns = {}
    for name in fields:
        kind, nullable = kinds[name]
        values = [d[name] for d in doc]
        found = set(map(type, values))
        none = {type(None)} if nullable or kind is float else set()
        allowed = ({float, int} if kind is float else {kind}) | none
        if not found <= allowed:
            _refuse(cls, data, max_len)
        if kind is str:
            columns[name] = values
        elif type(None) in found:
            columns[name] = np.array([NAN if v is None else v for v in values], dtype=np.float64)
        else:
            columns[name] = np.array(values, dtype=np.float64 if kind is float else kind)
    return columns, cls.from_dict(doc[-1], f"{cls.__name__}[{len(doc) - 1}]")


def _refuse(cls, data, max_len: int):
    """Raise `decode_batch`'s error for a batch a faster check refused (it names record and field)."""
    decode_batch(cls, data, max_len)
    raise ServiceError(f"{cls.__name__} batch: does not fit the schema")  # decode_batch raised already


# ---------------------------------------------------------------------------------- per-tick streams
@_message
class Pose(Message):
    """``<prefix>/<machine>/pose``: the implement at one tick (vehicle service).

    Positions are metres in the field's metric CRS (its UTM zone): ``x_m, y_m`` the true position on
    the path, ``measured_x_m, measured_y_m`` the GNSS fix the controller works from.
    """

    run_id: str
    tick: int  # 0, 1, 2, ... within the run
    time_s: float  # simulation time
    x_m: float
    y_m: float
    measured_x_m: float
    measured_y_m: float
    heading_rad: float  # counter-clockwise from east
    speed_m_s: float  # true ground speed
    measured_speed_m_s: float  # what the ground-speed sensor reads (the controller uses this)
    implement_on: bool
    s_m: float  # distance along the planned path (section control reads the plan ahead of it)


@_message
class ShaftState(Message):
    """``<prefix>/<machine>/shaft``: the metering shaft at the end of one control period (controller).

    With several metering drives (``[implement] kind``, `services.sim.machines`) the shaft fields are
    the one shaft's that would meter what the drives meter together; ``drive_target_rpm`` holds each
    drive's own target (one element for the gated meter).
    """

    run_id: str
    tick: int
    time_s: float
    target_shaft_rpm: float
    shaft_rpm: float
    shaft_rev: float  # revolutions during this period
    current_a: float  # proportional-valve current
    drive_target_rpm: Floats  # each metering drive's target (one for the gated meter)


@_message
class RateSample(Message):
    """``<prefix>/<machine>/rate``: prescribed and applied rate at the predicted landing point (controller).

    ``applied_kg_ha`` is this period's metered mass over the area the sections that are on cover in
    the period (null at standstill or with all sections off); ``prescribed_kg_ha`` is null outside the
    map (policy "off"); ``width_on_m`` is the working width of the sections whose gates are open and
    ``section_mask`` which ones: a bitmask in hexadecimal, bit k the k-th section from the left
    (``"0x3f"``: six sections all on; `common.section_masks.section_masks`); ``drive_rate_kg_ha`` and
    ``drive_kg`` are each metering drive's prescription at its own landing point and its product this
    period (one element each for the gated meter; the products sum to ``metered_kg``).
    ``side_steps_on``: a spinner's steps on per side (left, right: 0 the side off, ``side_steps`` its
    whole reach) where coverage control shortens its sides in steps; left out otherwise.
    """

    run_id: str
    tick: int
    time_s: float
    landing_x_m: float
    landing_y_m: float
    prescribed_kg_ha: float
    applied_kg_ha: float
    metered_kg: float
    width_on_m: float
    section_mask: str
    implement_on: bool
    drive_rate_kg_ha: Floats  # each metering drive's prescription at its own landing point
    drive_kg: Floats  # each metering drive's product this period (one for the gated meter)
    side_steps_on: Steps | None = None  # a spinner's steps on, left and right (only where it steps)


# ------------------------------------------------------------------------------------------ map
@_message
class MapRate(Message):
    """Reply of ``<prefix>/map/rate`` for one point (what ``vrsim map sample --json`` prints): the rate
    in kg/ha and in the map's own unit, `rate_unit`."""

    rate_kg_ha: float | None  # null outside the map, on nodata cells and for a map not in a mass rate
    rate: float | None        # in rate_unit; null outside the map and on nodata cells
    rate_unit: str            # the map's unit (maps.Grid.map_unit)
    inside: bool
    row: int | None
    col: int | None


def decode_points(data, max_points: int = MAX_POINTS,
                  max_bytes: int = MAX_POINTS_BYTES) -> tuple[np.ndarray, np.ndarray, bool]:
    """The batch body of ``<prefix>/map/rate``: ``{"x": [...], "y": [...]}`` (map CRS) or
    ``{"lat": [...], "lon": [...]}`` (WGS84 degrees); at most ``max_bytes`` (checked before parsing)
    and ``max_points`` points (checked before converting).

    Returns
    -------
    (first, second, geographic) : (ndarray (n,), ndarray (n,), bool)
        x, y in the map's CRS, or lon, lat with ``geographic`` True.
    """
    # A valid body has 2n - 1 commas for n points: more, and it holds too many points (or is not a
    # body), refused before orjson turns millions of values into Python floats.
    most = (b",", 2 * max_points, f"more than {max_points:,} points in one query (a reply must stay under "
                                  "the router's message limit: send batches)")
    doc = _loads(data, "map/rate batch", max_bytes, most)
    if not isinstance(doc, dict) or set(doc) not in ({"x", "y"}, {"lat", "lon"}):
        keys = sorted(doc) if isinstance(doc, dict) else short(doc)
        raise ServiceError(f"map/rate batch: body must be {{\"x\": [...], \"y\": [...]}} or "
                           f"{{\"lat\": [...], \"lon\": [...]}}, got keys {keys}")
    geo = "lat" in doc
    names = ("lon", "lat") if geo else ("x", "y")
    arrays = []
    for name in names:
        values = doc[name]
        if not isinstance(values, list):
            raise ServiceError(f"map/rate batch: {name} must be an array of numbers, got {short(values)}")
        if len(values) > max_points:
            raise ServiceError(f"map/rate batch: {len(values):,} points, at most {max_points:,} per query")
        # type() rather than isinstance: bools (an int subclass) and numeric strings are refused.
        if not set(map(type, values)) <= {float, int}:
            bad = next(v for v in values if type(v) is not float and type(v) is not int)
            raise ServiceError(f"map/rate batch: {name} holds a non-number {short(bad)}")
        arr = np.array(values, dtype=np.float64)
        arrays.append(arr)
    first, second = arrays
    if len(first) != len(second):
        raise ServiceError(f"map/rate batch: {names[0]} has {len(first)} values, {names[1]} {len(second)}")
    bad = ~np.isfinite(first) | ~np.isfinite(second)
    if geo:
        bad |= (np.abs(second) > 90.0) | (np.abs(first) > 180.0)
    if bad.any():
        i = int(np.argmax(bad))
        raise ServiceError(f"map/rate batch: point {i} ({names[0]}={float(first[i])!r}, "
                           f"{names[1]}={float(second[i])!r}) "
                           f"is not finite{' or out of range' if geo else ''}")
    return first, second, geo


ENCODE_CHUNK = 100_000  # points encoded at a time: their dicts take ~25 MB, not ~250 MB for a million


def encode_rates(rate_kg_ha: np.ndarray | None, rate: np.ndarray, rate_unit: str, inside: np.ndarray,
                 row: np.ndarray, col: np.ndarray) -> bytes:
    """The batch reply of ``<prefix>/map/rate``: a JSON array of `MapRate` objects; `rate` in
    `rate_unit`, `rate_kg_ha` None for a map whose rates are not in a mass unit (all null).

    orjson writes NaN rates (nodata) as null and floats as their shortest round-trip text, as
    json.dumps would: ~1 us per point, a dict each (outside points share one dict), `ENCODE_CHUNK`
    points at a time so that memory holds the reply's bytes and one chunk's dicts.
    """
    outside = ~np.asarray(inside, bool)
    parts = []
    away = {"rate_kg_ha": None, "rate": None, "rate_unit": rate_unit, "inside": False, "row": None,
            "col": None}  # outside points share one dict
    for a in range(0, len(rate), ENCODE_CHUNK):
        b = a + ENCODE_CHUNK
        rates, rows, cols = rate[a:b].tolist(), row[a:b].tolist(), col[a:b].tolist()
        masses = [None] * len(rates) if rate_kg_ha is None else rate_kg_ha[a:b].tolist()
        docs = [{"rate_kg_ha": m, "rate": r, "rate_unit": rate_unit, "inside": True, "row": i, "col": j}
                for m, r, i, j in zip(masses, rates, rows, cols, strict=True)]
        for k in np.flatnonzero(outside[a:b]).tolist():
            docs[k] = away
        parts.append(dumps(docs)[1:-1])  # the objects, without the array's brackets
    return b"[" + b",".join(parts) + b"]"


# ------------------------------------------------------------------------------------- run control
CLOCKS = ("lockstep", "realtime")
SPEED_RANGE = (0.01, 1000.0)  # real-time speed factor
TICKS_PER_MESSAGE_RANGE = (1, 1000)


@_message
class RunStart(Message):
    """What scenario control sends each service to load (and the vehicle to drive) a run."""

    run_id: str
    scenario_text: str  # the scenario file's TOML text
    source: str  # names the scenario in error messages: its path, or "builtin:<name>"
    base_dir: str  # relative paths in the scenario resolve against this
    clock: str  # "lockstep" or "realtime"
    speed: float  # real-time speed factor (2 = twice as fast as the wall clock)
    ticks_per_message: int  # lockstep batching: ticks per pose message and control step

    def __post_init__(self):
        if self.clock not in CLOCKS:
            raise ServiceError(f"RunStart: clock must be one of {', '.join(CLOCKS)}, got {self.clock!r}")
        lo, hi = SPEED_RANGE
        if not (isinstance(self.speed, (int, float)) and lo <= self.speed <= hi):
            raise ServiceError(f"RunStart: speed must be within [{lo:g}, {hi:g}], got {self.speed!r}")
        lo, hi = TICKS_PER_MESSAGE_RANGE
        if not lo <= self.ticks_per_message <= hi:
            raise ServiceError(f"RunStart: ticks_per_message must be within [{lo}, {hi}], "
                               f"got {self.ticks_per_message!r}")


_END_REASONS = ("finished", "stopped", "failed", "interrupted")
_MAX_RUN_TICKS = 10**10  # far beyond any run (the default's 177,002 ticks; a field's cap, 10,000 ha)
_MAX_END_ERROR_CHARS = 2000


@_message
class RunEnd(Message):
    """What scenario control sends the monitor (``<prefix>/<machine>/monitor/end``) when a run ends: the
    run's last tick and why it ended, so the monitor's report can tell a whole run from a partial one.

    ``reason``: ``finished`` (the vehicle drove the whole path), ``stopped`` (``scenario/stop``),
    ``failed`` (the run failed: ``error`` says why, e.g. the controller died) or ``interrupted`` (the
    vehicle service went away or restarted mid-run: ``ticks`` is the last count scenario control saw).
    """

    run_id: str
    reason: str
    ticks: int  # ticks driven: 0 .. ticks - 1
    sim_time_s: float
    error: str  # why it failed or was interrupted ("" otherwise)

    def __post_init__(self):
        if self.reason not in _END_REASONS:
            raise ServiceError(f"RunEnd: reason must be one of {', '.join(_END_REASONS)}, "
                               f"got {self.reason!r}")
        if not 0 <= self.ticks <= _MAX_RUN_TICKS:
            raise ServiceError(f"RunEnd: ticks must be within [0, {_MAX_RUN_TICKS}], got {self.ticks!r}")
        if not (math.isfinite(self.sim_time_s) and self.sim_time_s >= 0.0):
            raise ServiceError(f"RunEnd: sim_time_s must be a finite number >= 0, got {self.sim_time_s!r}")
        if len(self.error) > _MAX_END_ERROR_CHARS:
            raise ServiceError(f"RunEnd: error is over {_MAX_END_ERROR_CHARS} characters")


@_message
class StepAck(Message):
    """Reply of ``<prefix>/<machine>/control/step``: the controller has processed these ticks."""

    run_id: str
    ticks: int  # ticks in this step
    last_tick: int


@_message
class RunStatus(Message):
    """Reply of ``<prefix>/<machine>/vehicle/status``: the run the vehicle drives."""

    state: str  # "idle", "starting", "running", "finished", "stopped" or "failed"
    run_id: str
    scenario: str
    clock: str
    ticks: int  # ticks driven so far
    sim_time_s: float
    wall_s: float  # wall time since the run started (building the world and SUMO's network included)
    drive_s: float  # wall time since the first tick
    error: str  # why it failed ("" otherwise)
    speed: float = 1.0  # the real-time factor asked (`RunStart.speed`; the realtime clock's pace)


@_message
class MonitorStatus(Message):
    """Reply of ``<prefix>/<machine>/monitor/status``: what the monitor has stored for a run."""

    run_id: str
    pose_records: int
    shaft_records: int
    rate_records: int
    ticks: int  # complete ticks: pose, shaft and rate all received for 0..ticks-1
    live_samples: int  # rate samples with the implement on and both rates known
    live_mae_kg_ha: float  # their mean |applied - prescribed| at the predicted landing point
    live_bias_kg_ha: float  # their mean applied - prescribed
    database: str
