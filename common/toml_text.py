"""TOML read safely: every TOML reader of vrsim (scenarios, sweeps, machine files, ``--set`` values,
controller specs, fuzzy rules) calls `loads_toml`, which refuses text over the byte cap and the
table and nesting caps before tomllib parses it.
"""

from __future__ import annotations

import re

from vrsim.common.errors import VrsimError
from vrsim.common.files import cap_for

__all__ = ["MAX_TOML_DEPTH", "MAX_TOML_TABLES", "loads_toml"]

# tomllib's work grows with the square of a dotted key's parts (a 50 KB ``a.a.a...`` key: 8 s), so a
# scan counts what makes it grow before it parses. A scenario has about ten tables, keys of two or
# three parts and arrays two deep.
MAX_TOML_TABLES = 256  # table headers ([x], [[x]]) plus dotted keys (a.b = 1), each a table made
MAX_TOML_DEPTH = 16  # parts of one dotted key or header; nesting of [ and {
_TOML_TOKENS = re.compile(
    r'"""(?:[^"\\]|\\[\s\S]|""?(?!"))*"{3,5}|\'\'\'(?:[^\']|\'\'?(?!\'))*\'{3,5}'  # multi-line strings
    r'|"""[\s\S]*|\'\'\'[\s\S]*'  # unterminated: tomllib stops there, and so does the scan
    r'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*'  # strings and comments: their dots are no keys
    r'|[\[\]{}=,.\n]')  # structure; the rest (bare keys, numbers) is skipped


def loads_toml(text: str, where: str, error=VrsimError) -> dict:
    """`tomllib.loads` of `text` once a scan found it within `MAX_TOML_TABLES` and `MAX_TOML_DEPTH`
    (and the toml byte cap); `where` starts the `error` raised otherwise. Every TOML reader of vrsim
    calls this; `tomllib.TOMLDecodeError` is left to the caller."""
    import tomllib

    if len(text) > cap_for("toml"):
        raise error(f"{where}: {len(text):,} characters is over the {cap_for('toml'):,}-byte cap for TOML")
    _scan_toml(text, where, error)
    return tomllib.loads(text)


def _scan_toml(text: str, where: str, error) -> None:
    """Refuse `text` over the TOML caps, counting keys' dots only where a key may stand (a line's or
    an inline table's start, a header): a float's dot is no key's."""
    tables = parts = 0
    stack: list[str] = []  # open brackets: "h" a header's, "[" an array's, "{" an inline table's
    key = line_start = True  # a key may come next; nothing but spaces before on this line
    for token in _TOML_TOKENS.finditer(text):
        char = token[0][0]
        if char in "\"'#":  # a string (part of a key or a value) or a comment: no structure
            continue
        if char == "." and key:
            parts += 1
            tables += parts == 1  # a dotted key or header makes tables; count each once
            if parts >= MAX_TOML_DEPTH:
                raise error(f"{where}: a dotted key of over {MAX_TOML_DEPTH} parts (TOML cap)")
        elif char in "[{":
            header = char == "[" and key and (line_start if not stack else stack[-1] == "h")
            tables += header and not stack
            stack.append("h" if header else char)
            key = header or char == "{"
            if len(stack) > MAX_TOML_DEPTH:
                raise error(f"{where}: values nested too deeply (over {MAX_TOML_DEPTH} levels of [ and "
                            "{, TOML cap)")
        elif char in "]}":
            stack = stack[:-1]
            key = False
        elif char != ".":  # "=", ",", a new line
            key = char == "\n" and not stack or char == "," and stack[-1:] == ["{"]
        parts = parts if char == "." else 0
        line_start = char == "\n"
        if tables > MAX_TOML_TABLES:
            raise error(f"{where}: over {MAX_TOML_TABLES} tables (headers and dotted keys, TOML cap)")
