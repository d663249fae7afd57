"""The field kinds of the vrsim messages (`services.bus.messages`) and the checks that decode them.

`check` turns a decoded JSON value into its field's kind or raises `common.ServiceError` naming the
message, the field (and the array element) and the offending value.
"""

from __future__ import annotations

import json
import math

from vrsim.common import ServiceError
from vrsim.vehicle.implement import MAX_SECTIONS
from vrsim.vehicle.spinner import MAX_SIDE_STEPS

NAN = math.nan


def check(value, kind, nullable: bool, where: str, name: str):
    """`value` (decoded JSON) as field `name` of `kind` (`KINDS`) of message `where`."""
    if kind is Floats:
        return _floats(value, where, name)
    if kind is Steps and value is not None:
        return _steps(value, where, name)
    if value is None:
        if kind is float and not nullable:
            return NAN
        if nullable:
            return None
    elif kind is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(value, kind):
        return value
    raise ServiceError(f"{where}: field {name} must be {kind.__name__}"
                       f"{' or null' if nullable or kind is float else ''}, got {short(value)}")


def _floats(value, where: str, name: str) -> list:
    """A `Floats` field's value as a list of floats, or the `ServiceError` naming the element."""
    if not isinstance(value, list) or not 1 <= len(value) <= MAX_SECTIONS:
        raise ServiceError(f"{where}: field {name} must be an array of 1 to {MAX_SECTIONS} numbers, "
                           f"got {short(value)}")
    out = []
    for i, v in enumerate(value):
        if v is not None and (type(v) not in (int, float)):
            raise ServiceError(f"{where}: field {name}[{i}] must be a number or null, got {short(v)}")
        out.append(NAN if v is None else float(v))
    return out


def _steps(value, where: str, name: str) -> list:
    """A `Steps` field's value, or the `ServiceError` naming the element."""
    if not isinstance(value, list) or len(value) != 2:
        raise ServiceError(f"{where}: field {name} must be an array of 2 integers, got {short(value)}")
    for i, v in enumerate(value):
        if type(v) is not int or not 0 <= v <= MAX_SIDE_STEPS:
            raise ServiceError(f"{where}: field {name}[{i}] must be an integer in [0, {MAX_SIDE_STEPS}], "
                               f"got {short(v)}")
    return value


def short(value) -> str:
    """`value` as JSON text, cut to 60 characters (for error messages)."""
    text = json.dumps(value) if not isinstance(value, (bytes, bytearray)) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class Floats(list):
    """A field's kind: a JSON array of 1 to `MAX_SECTIONS` numbers (null: NaN), one per metering drive
    (`services.sim.machines`). Decoding checks every element and gives a plain list of floats."""


class Steps(list):
    """A field's kind: a spinner's steps on per side (left, right), two integers in [0, `MAX_SIDE_STEPS`]
    (`services.sim.sections.SectionStates.steps_on`)."""


# A field's annotation -> (kind, nullable): what `services.bus.messages` fields may be.
KINDS = {"float": (float, False), "int": (int, False), "bool": (bool, False), "str": (str, False),
         "float | None": (float, True), "int | None": (int, True), "str | None": (str, True),
         "list": (list, False), "dict": (dict, False), "Floats": (Floats, False),
         "Steps | None": (Steps, True)}
