"""What every machine kind's run-time part implements (`Machine`); docs/machines.md explains it."""

from __future__ import annotations

import dataclasses
import sys
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from vrsim.controller import PlantParams
from vrsim.maps.footprint import Strips
from vrsim.services.sim.machines.check import MachineCheck, shaft_check
from vrsim.services.sim.section_landing import StripPlan
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle import Implement
from vrsim.vehicle.machines import MachineSpec


class Machine(ABC):
    """A machine kind at run time: its metering drives and where their product lands.

    Metering: `drives` drives, each run by its own control loop (`controller.build_loop(..., n=drives)`:
    one lifted matrix product per period for all of them), each turning ``kg_per_rev *
    drive_share[d]`` per revolution. Each drive's target comes from the rate at its own landing point
    (`landing`) and its own ground speed (`drive_targets`); `services.sim.core.ControlCore` looks the
    rates up and applies the map's policy, then `ControlCore._metered_kg` turns revolutions into kg.

    Deposition: `deposition` plans where each drive's product lands (a `maps.footprint` kind and the
    masses of its items, linear in the product), through the one deposition engine (`maps.AsApplied`,
    `maps.ColumnDeposit`).

    A kind is one entry: the subclass names its `kind`, its `keys` and its `footprint`, and
    `services.sim.machines.registry.register_machine` registers all three (docs/machines.md, "Adding a
    kind").

    Parameters
    ----------
    implement : vehicle.Implement
        Of this kind (``implement.kind == kind``); its ``machine`` holds the kind's own keys.
    field_polygon : shapely geometry, optional
        The field boundary in the grid's CRS, for kinds that act on it (a spinner's border spreading);
        None: no boundary known (product is thrown as if the field went on).
    """

    kind: ClassVar[str] = ""
    keys: ClassVar[type[MachineSpec]]
    """The kind's own ``[implement]`` keys (`vehicle.machines.MachineSpec`; ``KIND`` is `kind`)."""
    footprint: ClassVar[type] = Strips
    """The `maps.footprint` kind its `deposition` plan's ``footprint()`` gives: strips by default."""
    product_form: ClassVar[str] = "granular"
    """The ``[product] form`` the machine meters; it picks the calibration test `vrsim calibrate` runs
    (`services.sim.calibrate`: a granular meter's rotor test, a liquid's catch test)."""

    def __init__(self, implement: Implement, field_polygon=None):
        self.implement = implement
        self.field_polygon = field_polygon

    @property
    def drives(self) -> int:
        """How many metering drives (and control loops) the machine has."""
        return 1

    @property
    def drive_share(self) -> np.ndarray:
        """Each drive's share of the implement's ``kg_per_rev`` per revolution, shape (drives,)."""
        return np.ones(1)

    @property
    def side_steps(self) -> int:
        """In how many steps each side's spread shortens over treated ground (the section switch's
        bands per side, `services.sim.sections.SectionSwitch`); 1: sections only on or off."""
        return 1

    @property
    def loop_quantity(self) -> tuple[str, str]:
        """What each drive's loop holds on target, and its unit, as `vrsim controller analyze` names them:
        a metering shaft's speed, rpm; a kind with another actuator says its own (a sprayer's flow)."""
        return "shaft speed", "rpm"

    def loop_plant(self, plant: PlantParams, scenario, grid) -> PlantParams:
        """The plant each drive's loop closes: the scenario's shaft plant (`services.sim.core.plant_for`)
        for a metering shaft; a kind with another actuator (a sprayer's flow loop) gives its own, and
        refuses a `scenario` it cannot run (`ScenarioError`). `grid`: the prescription (a working point)."""
        return plant

    def machine_check(self, lo_rate_kg_ha: float, hi_rate_kg_ha: float, speed_range_m_s: tuple[float, float],
                      density_kg_l: float | None, working_speed_m_s: float) -> MachineCheck:
        """Whether the machine can apply the map's lowest positive and highest rate inside the field
        (kg/ha; NaN: none positive) at working speeds within `speed_range_m_s`, before anything moves
        (`services.sim.limits.machine_check`): by default the metering shaft's range
        (`services.sim.machines.check.shaft_check`). A kind with another actuator checks it and gives its own
        `MachineCheck` (a sprayer: its nozzles, with the product's `density_kg_l` and a nozzle size
        suggested at `working_speed_m_s`); `VehicleError` where it cannot at any speed."""
        return shaft_check(self.implement, lo_rate_kg_ha, hi_rate_kg_ha, speed_range_m_s)

    def kg_per_rev(self, product) -> float:
        """What one revolution of a drive's loop meters, kg, as configured (`vehicle.product.metered_kg`
        applies `product`'s calibration error and flow variability to it): ``[implement] kg_per_rev``."""
        return self.implement.kg_per_rev

    def unlimited_targets(self, rate_kg_ha: np.ndarray, states: SectionStates, product) -> np.ndarray:
        """Each drive's target for its rate with the machine's range lifted (the error split's reference
        that applies what the map asks, `services.sim.error_split`): a shaft without a speed range."""
        unlimited = dataclasses.replace(self.implement, shaft_rpm_min=0.0, shaft_rpm_max=sys.float_info.max)
        return type(self)(unlimited, self.field_polygon).drive_targets(rate_kg_ha, states)

    def configured_kg(self, rev, product) -> np.ndarray:
        """What `rev` revolutions meter by the configured constant, kg: ``[implement] kg_per_rev``."""
        return self.implement.mass_kg(rev)

    def limited(self, control: dict, product=None) -> np.ndarray:
        """Where a drive's target (``control["drive_target_rpm"]``, a run's control arrays) sits on a bound
        of the machine's range, bool (n,): a closed drive's target is 0, never on a bound, so any
        drive's flags the tick. `product`: the run's, for a kind whose range depends on it (a sprayer's
        nozzles pass less of a denser liquid); a shaft's does not."""
        return self.implement.shaft_limited(control["drive_target_rpm"]).any(axis=1)

    def transverse_pattern(self) -> tuple[np.ndarray, np.ndarray] | None:
        """What one straight pass lays across its path with every section open, for the spread-pattern
        figures (`services.sim.spread_pattern`): lateral offsets (m, increasing, left positive) and
        relative mass per metre there (linear between, zero beyond); None for a kind without a spread
        pattern (strips side by side: a spread CV does not apply to it), the default."""
        return None

    @abstractmethod
    def landing(self, motion: Motion, lead_s: float) -> tuple[np.ndarray, ...]:
        """Where product metered now lands, `lead_s` s ahead along the predicted arc (`Motion.ahead`:
        the sensed speed, acceleration and yaw rate): the implement's centre (x_m, y_m), shape (n,),
        and each drive's landing point (x_m, y_m), shape (n, drives)."""

    @abstractmethod
    def drive_open(self, states: SectionStates) -> np.ndarray:
        """Whether each drive's product reaches the ground in each tick, bool (n, drives)."""

    def shut_off(self, drive_target: np.ndarray) -> np.ndarray:
        """Where a shut-off stops each drive's product whatever its loop does, bool (n, drives), from
        the drives' targets (`drive_targets`): nowhere by default (a shaft at a zero target slows to a
        stop and meters while it turns)."""
        return np.zeros(np.shape(drive_target), bool)

    def drive_speed_m_s(self, motion: Motion) -> np.ndarray:
        """Each drive's ground speed as the machine senses it, m/s (n, drives): the centre's sensed
        speed for every drive unless a kind's drives have their own (the controllers' context)."""
        return np.broadcast_to(motion.speed_m_s[:, None], (len(motion.speed_m_s), self.drives))

    @abstractmethod
    def drive_targets(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        """Each drive's target shaft speed, rpm (n, drives): for the rate at its landing point (kg/ha,
        (n, drives)) at its own ground speed, within the shaft's range; 0 where its product is shut."""

    @abstractmethod
    def combined(self, per_drive: np.ndarray) -> np.ndarray:
        """A machine-level value per tick (n,) of per-drive values (n, drives): the speed of one shaft
        that would meter what the drives meter together (the drives' speeds weighted by their shares)."""

    @abstractmethod
    def prescribed(self, rate_kg_ha: np.ndarray, states: SectionStates) -> np.ndarray:
        """The machine-level prescription per tick, kg/ha (n,), from each drive's (n, drives)."""

    @abstractmethod
    def deposition(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                   cell_m: float, ticks=None, tick_m: float | None = None, first_tick: int = 0) -> StripPlan:
        """Where the product lands, before any product: a plan with ``footprint()`` (a `maps.footprint`
        kind), ``mass_kg(product)`` (each item's kg, linear in `deposit_kg`'s product; (ticks, ..., m)
        columns give (items, m)) and ``pass_index`` (items,), as
        `services.sim.section_landing.StripPlan`. Parameters as
        `services.sim.section_landing.StripPlan.of`'s (`ticks`: only these; `tick_m`, `first_tick`: a
        tick's travel and where the track begins in a run accounted part by part)."""

    def ownership(self, track: dict, states: SectionStates, delay_s: float, period_s: float,
                  cell_m: float, ticks=None, tick_m: float | None = None,
                  first_tick: int = 0) -> StripPlan | None:
        """The ground each pass is set up to own, where the deposition lays product beyond it by design
        (a spinner's throw reaches into its neighbours' driving width): strips of the working width
        in `deposition`'s terms (same parameters, the same `deposit_kg` product), from which the
        overlap figures are read, so that a pattern's designed overlap is not counted as overlap.
        None, the default: the deposition's own strips are that ground."""
        return None

    def deposit_kg(self, control: dict) -> np.ndarray:
        """The product per tick in `deposition`'s terms, from a run's control arrays: ``metered_kg``
        (n,) for one drive, ``drive_kg`` (n, drives) for several."""
        return np.asarray(control["metered_kg"]) if self.drives == 1 else np.asarray(control["drive_kg"])
