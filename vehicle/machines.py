"""Machine kinds, as the machine is built: ``[implement] kind`` -> the kind's own keys, checked.

An implement (`vehicle.Implement`) has the keys every machine shares (working width, sections,
metering constant, shaft range, delivery delay, section control) and a *kind* that says how it meters
and where its product lands. Each kind registers a frozen dataclass of its own keys here
(`register_spec`); a scenario's ``[implement]`` table holds the shared keys and the kind's keys side
by side, and a key of another kind is refused naming the kind it belongs to. How a kind runs (its
drives, loops and footprint) lives in `services.sim.machines`, whose one registration of a kind
(`register_machine`: its keys, run-time part and footprint) checks that its keys are the ones
registered here, or registers them; docs/machines.md describes both.

Kinds:

- ``gated_meter`` (the default): one metering shaft for the whole width; each section's gate opens or
  closes its share of the width, and the shaft's product is shared between the open sections by
  width. No keys of its own.
- ``section_drives``: one metering drive per section, each turning its own roller. The smallest
  honest assumption about the rollers: section i's roller meters ``kg_per_rev * w_i / width_m`` per
  revolution (the shaft's roller cut into the sections' widths), so each drive turns at the speed the
  one shaft would for the same rate and ground speed, and the shaft's speed range holds for each.
  ``turn_compensation`` (true): each drive's target follows its section's own ground speed, the
  centre's minus the yaw rate times the section's offset; false: the centre's speed for all.
- ``sprayer``: a boom of nozzles behind a regulating valve and a flow meter; its keys are
  `vehicle.sprayer.SprayerSpec` (registered there).
- ``spinner``: a twin-disc spinner spreader (`vehicle.spinner.SpinnerSpec`): a drive per disc (side),
  product thrown across a spread width wider than the driving width in a transverse pattern.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

from vrsim.common.errors import VehicleError

__all__ = ["DEFAULT_KIND", "SPECS", "GatedMeter", "MachineSpec", "SectionDrives", "key_owner",
           "register_spec", "spec_class", "spec_keys"]

DEFAULT_KIND = "gated_meter"


@dataclass(frozen=True)
class MachineSpec:
    """Base of every kind's keys. Subclasses set `KIND` and, where the kind limits it, `MAX_SECTIONS`."""

    KIND: ClassVar[str] = ""
    MAX_SECTIONS: ClassVar[int | None] = None   # None: as many as the implement allows
    # Shared ``[implement]`` keys the kind has no use for (a sprayer's has no shaft): refused if given.
    UNUSED_KEYS: ClassVar[tuple[str, ...]] = ()

    def check_sections(self, sections: int) -> None:
        """Refuse more sections than the kind supports (`VehicleError` naming kind, limit and count)."""
        if self.MAX_SECTIONS is not None and sections > self.MAX_SECTIONS:
            raise VehicleError(f"Implement: kind {self.KIND!r} supports at most {self.MAX_SECTIONS} "
                               f"sections, got sections={sections}")

    def check_width(self, width_m: float) -> None:
        """Refuse a working width `width_m` (m) the kind cannot work at (`VehicleError`); any by default."""

    def resolved(self, base_dir: str) -> MachineSpec:
        """The keys with paths in them made absolute against `base_dir` (the scenario's folder) and
        the files they name checked; the keys themselves by default."""
        return self


SPECS: dict[str, type[MachineSpec]] = {}


def register_spec(cls: type[MachineSpec]) -> type[MachineSpec]:
    """Class decorator: register a kind's keys under its `KIND` (each kind once)."""
    if not cls.KIND or SPECS.get(cls.KIND, cls) is not cls:
        raise VehicleError(f"machine kind {cls.KIND!r}: empty or registered twice")
    SPECS[cls.KIND] = cls
    return cls


def spec_class(kind) -> type[MachineSpec]:
    """The keys' dataclass of kind `kind`; `VehicleError` naming the known kinds otherwise."""
    if not isinstance(kind, str) or kind not in SPECS:
        raise VehicleError(f"Implement: kind must be one of {', '.join(SPECS)}, got {kind!r}")
    return SPECS[kind]


def spec_keys(kind: str) -> tuple[str, ...]:
    """The keys of kind `kind` (its dataclass's fields)."""
    return tuple(f.name for f in dataclasses.fields(spec_class(kind)))


def key_owner(key: str) -> str | None:
    """The kind whose key `key` is (the first registered), or None."""
    return next((kind for kind in SPECS if key in spec_keys(kind)), None)


@register_spec
@dataclass(frozen=True)
class GatedMeter(MachineSpec):
    """``gated_meter``: one shaft, a gate per section (see the module's docstring). No keys."""

    KIND: ClassVar[str] = "gated_meter"


@register_spec
@dataclass(frozen=True)
class SectionDrives(MachineSpec):
    """``section_drives``: a metering drive per section (see the module's docstring).

    Attributes
    ----------
    turn_compensation : bool
        Each drive's target at its section's own ground speed (true) or the centre's (false).
    """

    KIND: ClassVar[str] = "section_drives"
    # A drive and a control loop per section: planters with a drive per row unit have up to 48 rows,
    # the most of any machine with a metering drive per section.
    MAX_SECTIONS: ClassVar[int | None] = 48

    turn_compensation: bool = True

    def __post_init__(self):
        if not isinstance(self.turn_compensation, bool):
            raise VehicleError("Implement: turn_compensation must be true or false, "
                               f"got {self.turn_compensation!r}")


# Kinds whose keys live in their own module register on import.
from vrsim.vehicle import spinner  # noqa: E402, F401
