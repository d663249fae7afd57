"""The ``[implement]`` table of a scenario file: the keys every machine shares and those of its kind.

A table holds `vehicle.Implement`'s own keys and the keys of its ``kind`` (`vehicle.machines`) side by
side; `implement_from_table` splits them, refuses a key of another kind naming the kind it belongs
to, and builds the implement with its kind's keys (`vehicle.machines.MachineSpec`).
"""

from __future__ import annotations

import dataclasses

from vrsim.common import ScenarioError, VrsimError
from vrsim.services.sim.tables import build, no_unknown, with_units
from vrsim.vehicle import Implement
from vrsim.vehicle.machines import DEFAULT_KIND, SPECS, key_owner, spec_class, spec_keys

IMPLEMENT_KEYS = {f.name for f in dataclasses.fields(Implement) if f.init} - {"machine"}
_DEFAULTS = {f.name: f.default for f in dataclasses.fields(Implement)}


def implement_from_table(table: dict, source: str, base_dir: str = ".") -> Implement:
    """An ``[implement]`` table -> `vehicle.Implement`. A key of another kind, an unknown kind or key,
    and what the dataclasses refuse raise a `ScenarioError` naming `source`, the key and the value.
    Paths among the kind's keys are relative to `base_dir` (`vehicle.machines.MachineSpec.resolved`)."""
    kind = table.get("kind", DEFAULT_KIND)
    try:
        spec = spec_class(kind)
    except VrsimError as exc:
        raise ScenarioError(f"{source}: [implement] {exc}") from None
    # Lengths, speeds and pressures given with a unit ("120 ft"), under the key's own name (width_m).
    table = with_units(table, IMPLEMENT_KEYS | set(spec_keys(kind)), source, "implement")
    # A key the kind has no use for, set to anything but its default, would be silently ignored; at its
    # default (a file written for another kind, its kind changed by --set) it changes nothing.
    unused = sorted(k for k in set(table) & set(spec.UNUSED_KEYS) if table[k] != _DEFAULTS[k])
    if unused:
        raise ScenarioError(f"{source}: [implement] {unused[0]} is not a key of kind {kind!r}, which has no "
                            f"use for it (got {table[unused[0]]!r})")
    own = {k: v for k, v in table.items() if k in IMPLEMENT_KEYS}
    rest = {k: v for k, v in table.items() if k not in IMPLEMENT_KEYS}
    for key in sorted(rest):
        owner = key_owner(key)
        if owner is not None and owner != kind:
            raise ScenarioError(f"{source}: [implement] {key} is a key of kind {owner!r}, not of kind "
                                f"{kind!r} (got {rest[key]!r})")
    no_unknown(rest, IMPLEMENT_KEYS | set(spec_keys(kind)), source, "implement")
    machine = build(spec, rest, source, "implement")
    try:
        machine = machine.resolved(base_dir)
    except VrsimError as exc:
        raise ScenarioError(f"{source}: [implement] {exc}") from None
    return build(Implement, {**own, "machine": machine}, source, "implement")


def implement_table(implement: Implement) -> dict:
    """`implement` as its ``[implement]`` table: the shared keys and its kind's, side by side."""
    table = {f.name: getattr(implement, f.name) for f in dataclasses.fields(implement) if f.init
             and f.name not in implement.machine.UNUSED_KEYS}
    machine = table.pop("machine")
    return {**table, **dataclasses.asdict(machine)}


def changed_implement(current: Implement, changes: dict, source: str, base_dir: str = ".") -> Implement:
    """`services.sim.scenario.with_changes` of ``[implement]``: keys as in a file (paths relative to
    `base_dir`); a change of kind drops the old kind's keys."""
    kept = implement_table(current)
    kind = changes.get("kind", current.kind)
    if kind != current.kind:
        unused = spec_class(kind).UNUSED_KEYS if kind in SPECS else ()
        kept = {k: v for k, v in kept.items() if k in IMPLEMENT_KEYS and k not in unused}
    return implement_from_table({**kept, **changes}, source, base_dir)
