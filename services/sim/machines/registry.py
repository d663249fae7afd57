"""The registry of machine kinds' run-time parts: ``[implement] kind`` -> a `Machine` class."""

from __future__ import annotations

from common import ScenarioError
from vehicle import Implement
from vehicle.machines import SPECS

MACHINES: dict[str, type] = {}


def register_machine(cls: type) -> type:
    """Class decorator: register a `services.sim.machines.base.Machine` subclass under its ``kind``,
    which `vehicle.machines` must know (the kind's keys; each kind once)."""
    if cls.kind not in SPECS:
        raise ValueError(f"machine kind {cls.kind!r} has no keys in vehicle.machines (register_spec)")
    if MACHINES.get(cls.kind, cls) is not cls:
        raise ValueError(f"machine kind {cls.kind!r} is registered twice")
    MACHINES[cls.kind] = cls
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
