"""The registry of machine kinds: ``[implement] kind`` -> a `Machine` class, the one entry of a kind.

A kind is registered once, by its run-time part (`register_machine`): a `Machine` subclass naming its
``kind``, its keys (``keys``, a `vehicle.machines.MachineSpec` dataclass) and its footprint
(``footprint``, a `maps.footprint` kind). Registering it fills the three registries a run reads, so
they cannot disagree: `MACHINES` here, `vehicle.machines.SPECS` (the keys a scenario's ``[implement]``
table is read with; a kind whose keys `vehicle` registered itself must name that same class) and
`maps.footprint.FOOTPRINTS` (a footprint registered once, shared by kinds that lay strips).
"""

from __future__ import annotations

from vrsim.common import ScenarioError
from vrsim.maps.footprint import FOOTPRINTS, register_footprint
from vrsim.vehicle import Implement
from vrsim.vehicle.machines import SPECS, MachineSpec, register_spec

MACHINES: dict[str, type] = {}


def register_machine(cls: type) -> type:
    """Class decorator: register a `services.sim.machines.base.Machine` subclass under its ``kind``
    (each kind once), with its keys (``cls.keys``, whose ``KIND`` is the kind: registered in
    `vehicle.machines.SPECS` unless `vehicle` holds them already) and its footprint (``cls.footprint``,
    registered in `maps.footprint.FOOTPRINTS` unless it is there already). `ValueError` naming what
    disagrees, before any registry changes."""
    kind = getattr(cls, "kind", "")
    if MACHINES.get(kind, cls) is not cls:
        raise ValueError(f"machine kind {kind!r} is registered twice")
    keys = getattr(cls, "keys", None)
    if not (isinstance(keys, type) and issubclass(keys, MachineSpec) and keys.KIND == kind):
        raise ValueError(f"machine kind {kind!r} has no keys: set its class attribute 'keys' to a "
                         f"vrsim.vehicle.machines.MachineSpec dataclass whose KIND is {kind!r}")
    if SPECS.get(kind, keys) is not keys:
        raise ValueError(f"machine kind {kind!r}: its keys {keys.__name__} are not the ones registered in "
                         f"vrsim.vehicle.machines ({SPECS[kind].__name__})")
    footprint = getattr(cls, "footprint", None)
    name = getattr(footprint, "kind", None)
    if not isinstance(name, str) or FOOTPRINTS.get(name, footprint) is not footprint:
        raise ValueError(f"machine kind {kind!r}: its footprint {footprint!r} is not a maps.footprint kind "
                         "of its own name")
    if kind not in SPECS:
        register_spec(keys)
    if name not in FOOTPRINTS:
        register_footprint(footprint)
    MACHINES[kind] = cls
    return cls


def machine_kinds() -> tuple[str, ...]:
    """The kinds that run, in registration order."""
    return tuple(MACHINES)


def machine_for(implement: Implement, field_polygon=None):
    """The run-time part of `implement`'s kind (on the field `field_polygon`, shapely, in the grid's
    CRS, where the kind acts on the boundary); `ScenarioError` naming the known kinds otherwise."""
    try:
        cls = MACHINES[implement.kind]
    except KeyError:
        raise ScenarioError(f"[implement] kind must be one of {', '.join(MACHINES)}, "
                            f"got {implement.kind!r}") from None
    return cls(implement, field_polygon)
