"""A scenario as data and as the text of a scenario file: `as_dict` (summary.json, the services),
`to_toml` (a file `services.sim.scenario.parse` reads back to the same scenario: the report's scenario
as run), `toml_value` (one value as TOML writes it).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from typing import Any

from vrsim.common import ScenarioError
from vrsim.services.sim.machines.keys import implement_table
from vrsim.services.sim.scenario import TABLES, Scenario

__all__ = ["as_dict", "to_toml", "toml_value"]


def as_dict(scenario: Scenario) -> dict[str, Any]:
    """The scenario as plain data (for summary.json and the services)."""
    out = {}
    for f in dataclasses.fields(scenario):
        value = getattr(scenario, f.name)
        if f.name == "implement":
            out[f.name] = implement_table(value)
        else:
            out[f.name] = dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
    return out


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def to_toml(scenario: Scenario) -> str:
    """The scenario as the text of a scenario file that `parse` reads back to the same scenario.

    Unset keys (None) are left out; the files it names (``[field] file``, ``[map] file``) are written
    as absolute paths, so the text loads from any folder; ``[plant]`` leaves out the transmission
    ratio and shaft-speed limit, which ``[implement]`` describes. Written from the scenario as run
    (`services.sim.as_run.as_run`), it reruns the run with every value shown.
    """
    lines = [f"{key} = {toml_value(getattr(scenario, key))}" for key in ("name", "seed", "description")]
    for key in TABLES:
        lines += ["", f"[{key}]"]
        lines += [f"{_toml_key(k)} = {toml_value(v)}" for k, v in _table(scenario, key).items()
                  if v is not None]
    return "\n".join(lines) + "\n"


def _table(scenario: Scenario, key: str) -> dict:
    """Table `key` of `scenario` as a scenario file writes it (see `to_toml`)."""
    value = getattr(scenario, key)
    table = {f.name: getattr(value, f.name) for f in dataclasses.fields(value) if f.init}
    if key == "implement":
        table = implement_table(value)
    if key in ("field", "map") and table["file"] is not None:
        table["file"] = os.path.abspath(scenario.path(table["file"]))
    if key == "plant":
        for machine in ("transmission_ratio", "shaft_rpm_max"):
            del table[machine]
    if key == "controller":
        table = {("class" if k == "class_name" else k): v for k, v in table.items()}
    return table


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.fullmatch(key) else json.dumps(key)


def toml_value(value) -> str:
    """`value` (bool, int, float, str, list, tuple or dict of them) as a scenario file writes it, a
    TOML value; a float by `repr`, which reads back to the same number.

    Raises
    ------
    ScenarioError
        A value of another type (None: a TOML file leaves the key out).
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(int(value))
    if isinstance(value, float):
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)   # a JSON string is a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        items = [f"{_toml_key(k)} = {toml_value(v)}" for k, v in value.items() if v is not None]
        return "{ " + ", ".join(items) + " }" if items else "{}"
    raise ScenarioError(f"{type(value).__name__} {value!r} has no TOML form")
