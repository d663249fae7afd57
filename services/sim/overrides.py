"""Dotted-key overrides of a scenario: ``vrsim run --set controller.kp=0.8``, the axes of a sweep, and
the tables of a machine file (``--machine machine_fit.toml``, `machine_overrides`).

An override is a (dotted key, value) pair applied to the parsed TOML document *before* the scenario
loader checks it, so an overridden value is checked exactly like one written in the file, by the same
code and with the same messages (file, table, key, value). ``seed=3`` sets a top-level key,
``implement.sections=12`` a key of a table, ``map.params.mean_kg_ha=150`` a key of a nested table.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Iterable
from typing import Any

from vrsim.common import ScenarioError, files
from vrsim.common.toml_text import loads_toml

Override = tuple[str, Any]


def key_parts(key: str, where: str) -> list[str]:
    """The parts of dotted `key` (``"controller.kp"`` -> ``["controller", "kp"]``).

    Raises
    ------
    ScenarioError
        An empty key or an empty part (``"controller..kp"``); `where` names the origin in the message.
    """
    parts = key.split(".")
    if not key or any(not p.strip() or p != p.strip() for p in parts):
        raise ScenarioError(f"{where}: {key!r} is not a dotted key like controller.kp")
    return parts


def _parse_value(text: str) -> Any:
    """A command-line value read as a TOML value (``0.8``, ``12``, ``true``, ``"x"``, ``[1, 2]``,
    ``{ a = 1 }``); text that is not a TOML value is taken as a string (``dgps``)."""
    try:
        return loads_toml(f"v = {text}", "--set value", ScenarioError)["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_assignment(text: str) -> Override:
    """``"KEY=VALUE"`` of ``--set`` as (dotted key, value); the key is checked, the value parsed."""
    key, sep, value = text.partition("=")
    if not sep:
        raise ScenarioError(f"--set {text!r}: expected KEY=VALUE, e.g. controller.kp=0.8")
    key = key.strip()
    key_parts(key, f"--set {text!r}")
    return key, _parse_value(value.strip())


def apply(doc: dict, overrides: Iterable[Override], source: str) -> dict:
    """A copy of TOML document `doc` with each (dotted key, value) set; tables on the way are created.

    Raises
    ------
    ScenarioError
        A key that goes through a value that is not a table (``controller.kp.x``), naming `source`.
    """
    out = copy.deepcopy(doc)
    for key, value in overrides:
        *tables, last = key_parts(key, source)
        node = out
        for depth, part in enumerate(tables):
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                path = ".".join(tables[:depth + 1])
                raise ScenarioError(f"{source}: cannot set {key}: {path} is {node!r}, not a table")
        node[last] = copy.deepcopy(value)
    return out


def machine_overrides(path: str) -> list[Override]:
    """The keys of a machine fragment (a TOML file of scenario tables, e.g. ``machine_fit.toml``) as
    dotted overrides (``response.dead_time_s``)."""
    data = files.read_bytes(path, "toml", ScenarioError)
    try:
        doc = loads_toml(data.decode("utf-8"), f"{path}: not a machine file", ScenarioError)
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ScenarioError(f"{path}: not a machine file (TOML): {exc}") from None
    out: list[Override] = []
    for table, keys in doc.items():
        if not isinstance(keys, dict):
            raise ScenarioError(f"{path}: {table} = {keys!r}: a machine file holds tables, like [response]")
        out += [(f"{table}.{key}", value) for key, value in keys.items()]
    return out
