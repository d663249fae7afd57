"""The one JSON encoding of vrsim: summaries, service replies, messages and command output.

NaN and infinities become ``null`` (JSON has no NaN: a figure that does not exist for a run, a rate
outside the map); numpy scalars and arrays become numbers and lists; dataclasses become objects of
their fields. Floats are written as their shortest round-trip text, so nothing is lost.
"""

from __future__ import annotations

import orjson

_OPTIONS = orjson.OPT_SERIALIZE_NUMPY


def dumps(doc, indent: bool = False) -> bytes:
    """`doc` as UTF-8 JSON bytes (two-space indented with `indent`)."""
    return orjson.dumps(doc, option=_OPTIONS | orjson.OPT_INDENT_2 if indent else _OPTIONS)


def dumps_text(doc, indent: bool = False) -> str:
    """`dumps` as text, for printing and text files."""
    return dumps(doc, indent).decode()
