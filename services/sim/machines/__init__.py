"""Machine kinds at run time: how each ``[implement] kind`` meters and where its product lands.

`machine_for` gives an implement's `Machine` (`services.sim.machines.base`); one module per kind
registers it (`register_machine`: the kind's one entry, naming its keys and footprint too):
`gated_meter` (one shaft, a gate per section; the default),
`section_drives` (a drive per section), `spinner` (a twin-disc spreader) and `sprayer` (a boom
sprayer: flow loops through its valve and flow meter, in litres). A kind's keys are
`vehicle.machines`'; ``keys`` reads a scenario's ``[implement]`` table. docs/machines.md: the
registry, each kind, how to add one.
"""

from vrsim.services.sim.machines import (  # noqa: F401  (register the kinds)
    gated_meter,
    section_drives,
    spinner,
    sprayer,
)
from vrsim.services.sim.machines.base import Machine
from vrsim.services.sim.machines.registry import machine_for, machine_kinds, register_machine

__all__ = ["Machine", "machine_for", "machine_kinds", "register_machine"]
