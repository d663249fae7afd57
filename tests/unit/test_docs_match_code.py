"""The reference pages say what the code has: every key of every scenario table is documented in
scenarios/README.md, and every signature docs/api.md gives (``name(params)`` in backticks) names
parameters the function has, in its order, with its defaults (`inspect.signature`)."""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import os
import re
import typing

import pytest

from tests.conftest import ROOT
from vrsim.services.sim import scenario
from vrsim.services.sim.machines.keys import IMPLEMENT_KEYS
from vrsim.vehicle.machines import SPECS, spec_keys

README = os.path.join(ROOT, "scenarios", "README.md")
API = os.path.join(ROOT, "docs", "api.md")
FENCE = re.compile(r"^```.*?^```", re.M | re.S)  # code blocks: calls in examples, not signatures


# ------------------------------------------------------------------------------ scenario keys
def table_keys() -> dict[str, set[str]]:
    """Every key a scenario file's tables take, read from the classes that parse them: the dataclass
    of each table (`services.sim.scenario.Scenario`'s field types), ``[implement]``'s own keys and every
    machine kind's, ``[controller]``'s `CONTROLLER_KEYS`; ``""``: the top-level keys."""
    types = typing.get_type_hints(scenario.Scenario)
    keys = {"": set(scenario.TOP_KEYS) - set(scenario.TABLES)}
    for table in scenario.TABLES:
        if table == "implement":
            keys[table] = set(IMPLEMENT_KEYS) | {key for kind in SPECS for key in spec_keys(kind)}
        elif table == "controller":
            keys[table] = set(scenario.CONTROLLER_KEYS)
        else:
            keys[table] = {f.name for f in dataclasses.fields(types[table]) if f.init}
    return keys


def documented_keys(text: str) -> dict[str, set[str]]:
    """The names in backticks of each ``| `[table]` | class | keys |`` row of scenarios/README.md (a
    span such as ``rectangle = {width_m, ...}`` names its first word), and ``""``: those in the text
    around the table (the top-level keys)."""
    rows, rest = {}, []
    for line in text.splitlines():
        found = re.match(r"\|\s*`\[(\w+)\]`\s*\|", line)
        names = {m.group(1) for m in re.finditer(r"`\s*([A-Za-z_]\w*)", line)}
        if found:
            rows[found.group(1)] = names
        else:
            rest.append(names)
    rows[""] = set().union(*rest)
    return rows


def undocumented(keys: dict[str, set[str]], docs: dict[str, set[str]]) -> dict[str, list[str]]:
    return {table: sorted(names - docs.get(table, set())) for table, names in keys.items()
            if names - docs.get(table, set())}


def test_every_scenario_key_is_documented_in_the_scenarios_readme():
    with open(README, encoding="utf-8") as fh:
        docs = documented_keys(fh.read())
    assert set(scenario.TABLES) <= set(docs), f"tables without a row: {set(scenario.TABLES) - set(docs)}"
    assert undocumented(table_keys(), docs) == {}


def test_the_key_check_finds_a_key_missing_from_its_row():
    text = ("| `[tractor]` | `vehicle.DriveConfig` | `working_speed_m_s` (2.5), `rectangle = {a, b}` |\n"
            "The top level: `name`, `seed`.\n")
    docs = documented_keys(text)
    assert docs["tractor"] == {"vehicle", "working_speed_m_s", "rectangle"} and docs[""] == {"name", "seed"}
    keys = {"tractor": {"working_speed_m_s", "headland_speed_m_s"}, "": {"name", "seed"}}
    assert undocumented(keys, docs) == {"tractor": ["headland_speed_m_s"]}


# ------------------------------------------------------------------------------- api signatures
# ``name(params)`` or ``name(params) -> type`` in backticks (one level of parentheses inside).
SIGNATURE = re.compile(r"`((?:[A-Za-z_]\w*\.)*[A-Za-z_]\w*)\(([^`()]*(?:\([^`()]*\)[^`()]*)*)\)"
                       r"(?:\s*->\s*[^`]*)?`", re.S)
# Where an unqualified name of the page lives: the stable names are `vrsim.services.sim`'s (or of the
# module the page named just before: `machine_kinds` after `vrsim.services.sim.machines.machine_for`).
HOMES = ("", *(f"vrsim.{home}." for home in (
    "services.sim", "services.sim.machines", "services.sim.streamed", "services.sim.overrides",
    "services.outputs.write", "services.bus")))
# Not functions of vrsim's modules: methods of a result, callbacks the caller writes, pandas, zenoh.
NOT_FUNCTIONS = {"result.to_pandas", "to_pandas", "as_grid", "cell_centres", "state", "track_sink",
                 "on_world", "pandas.read_parquet", "session.get"}


def documented_signatures(text: str) -> list[tuple[str, str]]:
    """(name, parameter text) of each signature in `text` outside code blocks."""
    return [(m.group(1), " ".join(m.group(2).split())) for m in SIGNATURE.finditer(FENCE.sub("", text))]


def resolve(name: str):
    """The object `name` names (a dotted path, or a name of one of `HOMES`), or None."""
    for home in HOMES:
        parts = (home + name).split(".")
        for cut in range(len(parts) - 1, 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ImportError:
                continue
            try:
                for attr in parts[cut:]:
                    obj = getattr(obj, attr)
            except AttributeError:
                break
            return obj
    return None


def _split(params: str) -> list[str]:
    """Top-level comma-separated parts of a parameter list."""
    parts, depth, current = [], 0, ""
    for char in params:
        depth += char in "([{"
        depth -= char in ")]}"
        if char == "," and depth == 0:
            parts.append(current.strip())
            current = ""
        else:
            current += char
    return [p for p in [*parts, current.strip()] if p]


def mismatch(name: str, params: str, signature: inspect.Signature) -> str | None:
    """What the documented ``name(params)`` says that `signature` does not have, or None. A list with
    ``...`` elides parameters: only the ones it names must exist (its values are an example's)."""
    code = list(signature.parameters.values())
    names = [p.name for p in code]
    elided = "..." in params
    documented = []
    for part in _split(params):
        if part == "...":
            continue
        key, _, default = part.partition("=")
        key = key.strip().lstrip("*")
        if not key.isidentifier():
            return None  # a call written out (`control_and_account(drive(scenario))`), no signature
        if key not in names:
            return f"{name}: no parameter {key!r} (the code's: {', '.join(names)})"
        documented.append((key, default.strip()))
    order = [names.index(key) for key, _ in documented]
    if order != sorted(order):
        return (f"{name}: documented in the order {', '.join(k for k, _ in documented)}; the code's is "
                f"{', '.join(names)}")
    if elided:
        return None
    required = [p.name for p in code if p.default is inspect.Parameter.empty
                and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    if [k for k, _ in documented][:len(required)] != required:
        return f"{name}: the code requires {', '.join(required) or 'nothing'} first"
    for key, default in documented:
        if not default:
            continue
        try:
            said = ast.literal_eval(default)
        except (ValueError, SyntaxError):
            continue  # an expression: not compared
        actual = signature.parameters[key].default
        if actual is inspect.Parameter.empty or actual != said or type(actual) is not type(said):
            shown = "none" if actual is inspect.Parameter.empty else repr(actual)
            return f"{name}: {key}={default} documented, the code's default is {shown}"
    return None


def test_every_signature_docs_api_gives_is_the_codes():
    with open(API, encoding="utf-8") as fh:
        found = [(n, p) for n, p in documented_signatures(fh.read()) if n not in NOT_FUNCTIONS]
    assert len(found) >= 20  # the page's Python half: load, run, run_streamed, calibrate, ...
    unknown = [name for name, _ in found if not callable(resolve(name))]
    assert unknown == [], f"docs/api.md names functions the code does not have: {unknown}"
    wrong = [m for name, params in found if (m := mismatch(name, params, inspect.signature(resolve(name))))]
    assert wrong == []


@pytest.mark.parametrize("params, message", [
    ("scenario, progress=None", None),
    ("scenario, progress=None, extra=1", "no parameter 'extra'"),
    ("progress=None, scenario", "documented in the order progress, scenario"),
    ("scenario, progress=1", "progress=1 documented, the code's default is None"),
    ("..., progress=None", None),
    ("progress=None", "the code requires scenario first"),
    ("g(scenario)", None),
])
def test_the_signature_check_finds_a_wrong_name_order_or_default(params, message):
    def f(scenario, progress=None, *, worker=None):
        return scenario, progress, worker

    found = mismatch("f", params, inspect.signature(f))
    assert (found is None) if message is None else (message in found), found
