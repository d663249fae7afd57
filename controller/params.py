"""Parameters of a controller kind: one frozen dataclass per kind, checked when it is made.

Each field is declared with `param` (default, bounds, allowed values); `KindParams.__post_init__`
checks every field against its declaration and then calls the kind's own cross-field `check`, so a
bad value fails at construction with a `ControllerError` naming the kind, the key and the value.
`from_dict` builds one from a TOML table (``[controller] params = {...}``), rejecting unknown keys.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

from vrsim.common import ControllerError, in_range
from vrsim.common.checks import number_rule


def param(default, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
          choices: tuple | None = None, number: bool = False) -> Any:
    """A checked parameter field.

    Parameters
    ----------
    default
        Default value; its type is the field's type (a float field also takes an int).
    lo, hi : float, optional
        Inclusive bounds of a number (``lo_open``: lo itself excluded).
    choices : tuple, optional
        The allowed values of a string.
    number : bool
        With ``default=None``: the field is an optional number.
    """
    return field(default=default, metadata={"lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices,
                                            "number": number or isinstance(default, float)})


def _problem(f: dataclasses.Field, value) -> str | None:
    """What is wrong with `value` for field `f`, or None."""
    meta = f.metadata
    if value is None:
        return None if f.default is None else "a value"
    if meta.get("choices"):
        return None if value in meta["choices"] else f"one of {', '.join(map(str, meta['choices']))}"
    if isinstance(f.default, bool):
        return None if isinstance(value, bool) else "true or false"
    if meta.get("number") or isinstance(f.default, int):
        whole = isinstance(f.default, int) and not meta.get("number")
        if whole and (isinstance(value, bool) or not isinstance(value, int)):
            return "a whole number"
        lo, hi, lo_open = meta["lo"], meta["hi"], meta["lo_open"]
        return None if in_range(value, lo, hi, lo_open) else number_rule(lo, hi, lo_open)
    if isinstance(f.default, str):
        return None if isinstance(value, str) else "a string"
    return None


@dataclass(frozen=True)
class KindParams:
    """Base of every kind's parameter dataclass; subclasses set `KIND` and may override `check`."""

    KIND: ClassVar[str] = ""

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            wrong = _problem(f, value)
            if wrong:
                raise ControllerError(f"controller {self.KIND} {f.name} must be {wrong}, got {value!r}")
            if f.metadata.get("number") and isinstance(value, int) and not isinstance(value, bool):
                object.__setattr__(self, f.name, float(value))
        self.check()

    def check(self) -> None:
        """Cross-field checks of the kind (raise `ControllerError` naming key and value)."""

    @classmethod
    def from_dict(cls, table: dict):
        """Build from a ``params`` table; unknown keys are an error naming them and the known ones."""
        if not isinstance(table, dict):
            raise ControllerError(f"controller {cls.KIND} params must be a table, got {table!r}")
        known = [f.name for f in fields(cls)]
        for key in table:
            if key not in known:
                raise ControllerError(f"controller {cls.KIND} params: unknown key {key!r} "
                                      f"(known: {', '.join(known)})")
        return cls(**table)

    def to_dict(self) -> dict:
        """The parameters as a plain dict (what `from_dict` takes back)."""
        return dataclasses.asdict(self)
