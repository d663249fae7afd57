"""Checks of TOML tables read into vrsim's files (a scenario, a sweep), with one shape of message.

Every refusal is a `ScenarioError` whose one line names the file (`source`), the table (``[section]``,
none for the top level), the key and the value, so a scenario and a sweep file report a bad key alike.
"""

from __future__ import annotations

import dataclasses
import math
import re

from vrsim.common import ScenarioError, VrsimError
from vrsim.maps.units import KEY_UNITS, key_unit, quantity_in


def _where(section: str) -> str:
    return f"[{section}] " if section else ""


def no_unknown(table: dict, known, source: str, section: str) -> None:
    """Refuse a key of `table` that is not in `known`.

    Parameters
    ----------
    table : dict
        The TOML table as read.
    known : iterable of str
        Its allowed keys (listed in the message).
    source : str
        The file (or origin) that the message names.
    section : str
        The table's dotted name (``"map.params"``), or "" for the top level.

    Raises
    ------
    ScenarioError
        ``"<source>: [<section>] unknown key 'x' (known: a, b, ...)"``, naming the first unknown key.
    """
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ScenarioError(f"{source}: {_where(section)}unknown key {unknown[0]!r} "
                            f"(known: {', '.join(sorted(known))})")


def typed(table: dict, key: str, kind: type, source: str, section: str, default=None):
    """``table[key]`` if it is of type `kind` (a bool is not an int), `default` if the key is absent.

    Parameters
    ----------
    table : dict
    key : str
    kind : type
        ``str``, ``int``, ``dict``, ...
    source, section : str
        As in `no_unknown`.
    default : optional
        What an absent key gives.

    Raises
    ------
    ScenarioError
        ``"<source>: [<section>] <key> must be <kind>, got <value>"``.
    """
    if key not in table:
        return default
    value = table[key]
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ScenarioError(f"{source}: {_where(section)}{key} must be {kind.__name__}, got {value!r}")
    return value


def _expected_type(f: dataclasses.Field):
    """The Python type a TOML value must have for dataclass field `f` (None: anything)."""
    default = f.default if f.default is not dataclasses.MISSING else (
        f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
    if isinstance(default, bool):
        return bool
    if isinstance(default, (int, float)):
        return (int, float) if isinstance(default, float) or "float" in str(f.type) else int
    if isinstance(default, (str, dict, list)):
        return type(default)
    text = str(f.type)
    if len([t for t in text.split("|") if t.strip() != "None"]) > 1:
        return None     # a union such as "float | str": the dataclass checks it
    for name, kind in (("float", (int, float)), ("int", int), ("str", str), ("bool", bool),
                       ("dict", dict), ("list", list)):
        if text.startswith(name):
            return kind
    return None


def build(cls, table: dict, source: str, section: str):
    """Configuration dataclass `cls` made from TOML `table`: unknown keys, values of the wrong type
    (a float where the field's default is one also takes an int; a bool is never a number) and
    non-finite numbers are refused before `cls` checks its own values.

    Raises
    ------
    ScenarioError
        Naming `source`, ``[section]``, the key and the value (what `cls` refuses, with its message).
    """
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    table = with_units(table, fields, source, section)
    no_unknown(table, fields, source, section)
    for key, value in table.items():
        kind = _expected_type(fields[key])
        if kind is None or value is None:
            continue
        bad_bool = isinstance(value, bool) and kind is not bool
        if bad_bool or not isinstance(value, kind):
            names = kind.__name__ if isinstance(kind, type) else "number"
            raise ScenarioError(f"{source}: [{section}] {key} must be {names}, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ScenarioError(f"{source}: [{section}] {key} must be finite, got {value!r}")
    try:
        return cls(**table)
    except VrsimError as exc:
        raise ScenarioError(f"{source}: [{section}] {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"{source}: [{section}] {exc}") from None


def with_units(table: dict, known, source: str, section: str) -> dict:
    """`table` with its lengths, speeds and pressures given with a unit in the unit of their key.

    A known key whose name ends in a unit of `maps.units.KEY_UNITS` (``width_m``, ``working_speed_m_s``,
    ``pressure_range_bar``), or the same name without that ending (``width``) where the key with it is
    known, may hold a number with a unit as a string (``"120 ft"``, ``"10 mph"``) or a list of such
    strings and numbers (``["15 psi", "60 psi"]``; a plain number is in the key's unit): each string
    becomes a number in the key's unit (`maps.units.quantity_in`), under the key's full name. A word
    under the full name ("fast") is left for the type check, which refuses it as any other.

    Raises
    ------
    ScenarioError
        ``"<source>: [<section>] <key> '<value>' is not a length (...)"``: a string that is no number
        with a unit of the key's kind, or one pint cannot read; a value given under both names.
    """
    out = {}
    for key, value in table.items():
        full = key if key in known else next((key + suffix for suffix, _, _ in KEY_UNITS
                                              if key + suffix in known and key_unit(key + suffix)), None)
        unit = key_unit(full) if full is not None else None
        # A word under the key's own name ("fast") is no quantity: its type is refused as any other's.
        if unit is None or not _has_text(value) or (full == key and isinstance(value, str)
                                                    and not _NUMBER_FIRST.match(value)):
            out[key] = value
            continue
        converted = _in_unit(value, key, unit, source, section)
        if full != key and full in table:
            raise ScenarioError(f"{source}: {_where(section)}{key} and {full}: give one of them, got "
                                f"{value!r} and {table[full]!r}")
        out[full] = converted
    return out


_NUMBER_FIRST = re.compile(r"\s*[-+]?\.?\d")  # what a number with a unit starts with


def _has_text(value) -> bool:
    return isinstance(value, str) or (isinstance(value, list) and any(isinstance(v, str) for v in value))


def _in_unit(value, key: str, unit: tuple[str, str], source: str, section: str):
    """A string (or the strings of a list) read as a number with a unit, in `unit` (`with_units`)."""
    try:
        if isinstance(value, list):
            return [quantity_in(v, *unit) if isinstance(v, str) else v for v in value]
        return quantity_in(value, *unit)
    except ValueError as exc:
        shown = value if len(repr(value)) <= 60 else f"{str(value)[:40]}..."
        raise ScenarioError(f"{source}: {_where(section)}{key} {shown!r} {exc}") from None
