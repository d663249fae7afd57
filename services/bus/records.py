"""How the monitor stores a per-tick stream's records (`services.bus.messages`) in SQLite, and back.

A record is a row keyed by (run_id, tick) with a column per other field: numbers and flags as REAL,
strings as TEXT, and each metering drive's values (``drive_target_rpm``, ``drive_rate_kg_ha``,
``drive_kg``: an array per record) and a spinner's steps on (``side_steps_on``) as their JSON text.
NaN is stored as NULL (a number) or ``null`` (in an array); an optional field left out as NULL.
"""

from __future__ import annotations

import numpy as np
import orjson

from vrsim.services.outputs.encode import dumps

NAN = float("nan")
_SCALARS = (float, int, bool)


def columns(cls) -> list[str]:
    """The fields of message class `cls` stored as columns (all but run_id and tick), in order."""
    return [name for name, _, _ in cls._spec if name not in ("run_id", "tick")]


def sql_types(cls) -> list[str]:
    """``name TYPE`` of each of `columns`: REAL for numbers and flags, TEXT for strings and arrays."""
    return [f"{name} {'REAL' if kind in _SCALARS else 'TEXT'}" for name, kind, _ in cls._spec
            if name not in ("run_id", "tick")]


def stored(value):
    """A field's value as its column holds it (an array as its JSON text)."""
    return dumps(value).decode() if isinstance(value, list) else value


def field_value(value, kind):
    """A column's value back as the field of `kind` it was: NaN for NULL (None for an optional array
    left out), a list from JSON text."""
    if value is None:
        return NAN if kind in _SCALARS else None
    if kind in _SCALARS or kind is str:
        return kind(value)
    return [NAN if v is None else v for v in orjson.loads(value)]


def drive_values(texts: list, drives: int, ticks: np.ndarray, name: str) -> np.ndarray:
    """The stored arrays of the per-drive field `name` (JSON texts, one per record, of ticks `ticks`)
    as (records, drives), NaN for null. A record whose array does not hold `drives` values (the run's
    machine has that many) raises `ValueError` naming its tick: the messages were checked when they
    came (`services.bus.messages`: 1 to 128 numbers or null), the machine is known only with the run."""
    rows = [orjson.loads(t) for t in texts]
    for tick, row in zip(ticks.tolist(), rows, strict=True):
        if len(row) != drives:
            raise ValueError(f"tick {tick}: {name} holds {len(row)} values, the machine has {drives} "
                             "drives")
    return np.array(rows, dtype=np.float64).reshape(len(rows), drives)


def steps_values(texts: list, side_steps: int, ticks: np.ndarray) -> dict:
    """The stored ``side_steps_on`` of the records of ticks `ticks` (JSON texts, NULL where left out)
    as ``{"side_steps_on": int (records, 2)}``, ``{}`` where every record left it out (a machine that
    does not shorten its sides in steps). A record without it beside others with it, one with it for
    a machine that does not step (`side_steps` 1), or one with a step beyond `side_steps` raises
    `ValueError` naming its tick (and element): the messages were checked when they came (two
    integers in [0, 16]), the machine is known only with the run."""
    held = np.array([t is not None for t in texts], dtype=bool)
    if not held.any():
        return {}
    if not held.all():
        raise ValueError(f"tick {int(ticks[np.argmin(held)])}: side_steps_on left out, other records "
                         "hold it")
    if side_steps < 2:
        raise ValueError(f"tick {int(ticks[0])}: side_steps_on held, but the machine does not shorten "
                         "its sides in steps")
    steps = np.array([orjson.loads(t) for t in texts], dtype=np.int64).reshape(len(texts), 2)
    bad = (steps < 0) | (steps > side_steps)
    if bad.any():
        row, side = np.argwhere(bad)[0]
        raise ValueError(f"tick {int(ticks[row])}: side_steps_on[{side}] is {int(steps[row, side])}, "
                         f"the machine's sides have {side_steps} steps")
    return {"side_steps_on": steps}


def fitting(records: list, cls, values: int) -> list:
    """The first of `records` (messages of `cls`) that hold at most `values` values together: each
    field but run_id and tick one, an array each of its elements (a reply's size grows with drives)."""
    arrays = [name for name, kind, _ in cls._spec if kind not in (*_SCALARS, str)]
    per = len(columns(cls)) - len(arrays) + np.array([sum(len(getattr(r, a) or ()) for a in arrays)
                                                      for r in records], dtype=np.int64).reshape(-1)
    return records[:int(np.searchsorted(np.cumsum(per), values, side="right"))]
