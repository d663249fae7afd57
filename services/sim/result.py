"""A run's result (`RunResult`): what it measured and its accounts, with the per-tick arrays the Python
API offers when the run kept them (`services.sim.run.run`) or what the outputs need when it was accounted
part by part (`services.sim.streamed.run_streamed`). Both come from the one accounting,
`services.sim.bounded.BoundedAccount`."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from vrsim.maps import AsApplied
from vrsim.services.sim import ticks
from vrsim.services.sim.accounting import Accounts
from vrsim.services.sim.aslog import run_point_log
from vrsim.services.sim.display import run_summary
from vrsim.services.sim.kept import Kept, PathPoints, SeriesWindow
from vrsim.services.sim.landing import Landing
from vrsim.services.sim.limits import MachineCheck
from vrsim.services.sim.metrics import LimitMetrics, MapMetrics, OverlapMetrics
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.transitions import TransitionMetrics
from vrsim.services.sim.world import World

__all__ = ["RunResult"]


@dataclass
class RunResult:
    """What a run measured and its accounts: the track and what the sensors read on it, the control
    loop's arrays, the sections' gates, the as-applied raster and the figures (``summary``, from
    `services.sim.metrics.METRICS` over `accounts`; callers add their own keys, such as ``out_dir``).
    The world, the track, where product landed and the field's cells are the accounts' `Setting`'s.

    Per tick (arrays of shape (ticks,), 50 ms ticks by default; docs/api.md lists every attribute):
    ``track`` (dict: the true path), ``measured_*`` (the sensors), ``control`` (dict keyed as
    `services.sim.core.CONTROL_KEYS`: the controller's look-ahead point and rate, target and actual
    shaft speed, current, metered kg, open width, the gates), ``landing`` (`services.sim.landing.
    Landing`: where each tick's product landed, the prescription there and the applied rate). One
    table of them all: `to_pandas` (`services.sim.ticks.tick_columns`).

    NaN in the per-tick rates: ``landing.applied_kg_ha`` (and the table's ``applied_kg_ha``) is a
    tick's metered kg over the strip its open sections covered, so it is NaN where no section is open
    or the strip is under 1 cm: with the implement lifted (turns, headland, the way to the first
    pass), with every section closed over covered ground, at a standstill (13.6 % of the default
    run's ticks: 12.8 % lifted, 0.8 % all sections closed). ``landing.prescribed_kg_ha`` and
    ``control["prescribed_kg_ha"]`` are NaN off the map. The run's figures (``summary``) are over the
    as-applied raster's cells, not over these ticks.
    """

    measured_x_m: np.ndarray
    measured_y_m: np.ndarray
    measured_speed_m_s: np.ndarray
    control: dict
    sections: SectionStates  # gates per tick and section, section widths and offsets, passes
    as_applied: AsApplied
    accounts: Accounts
    started_unix: float  # when the run (or the services run it was rebuilt from) started, Unix time
    # The error split's reference meters' figures (`services.sim.error_split`),
    # when the run computed them beside its accounting; None: computed when asked for.
    reference_figures: list[MapMetrics] | None = None
    # What a run accounted part by part (`services.sim.bounded`) kept for its outputs; None: the
    # in-process run, whose arrays give them (`kept`).
    kept_parts: Kept | None = None
    summary: dict = field(init=False)

    def __post_init__(self):
        self.summary = run_summary(self.accounts)   # and ``units``, the system its figures are shown in

    @property
    def world(self) -> World:
        return self.accounts.setting.world

    @property
    def bounded(self) -> bool:
        """Accounted part by part (`services.sim.bounded`, what `vrsim run` does): no per-tick arrays
        (``track``, ``control``, ``landing``, the measured arrays and ``sections`` are None); the track
        was written as it went, and `kept` holds what the other outputs need."""
        return self.kept_parts is not None

    @functools.cached_property
    def kept(self) -> Kept:
        """The path points, timeseries.png's window and the as-applied log (`services.sim.kept`)."""
        if self.kept_parts is not None:
            return self.kept_parts
        track, landing, control = self.track, self.landing, self.control
        path = PathPoints.for_ticks(len(track["x_m"]))
        path.add(track["x_m"], track["y_m"])
        series = SeriesWindow()
        series.add({"time_s": track["time_s"], "target_shaft_rpm": control["target_shaft_rpm"],
                    "shaft_rpm": control["shaft_rpm"], "prescribed_kg_ha": landing.prescribed_kg_ha,
                    "applied_kg_ha": landing.applied_kg_ha}, track["implement_on"])
        log = run_point_log(self.world, track, control, landing.applied_kg_ha, self.started_unix,
                            self.world.scenario.output.log_rate_hz)
        return Kept(path.xy(), series.finish(), log)

    @property
    def track(self) -> dict:
        return self.accounts.setting.track

    @property
    def landing(self) -> Landing:
        return self.accounts.setting.landing

    @property
    def in_field(self) -> np.ndarray:
        return self.accounts.setting.in_field

    @property
    def worked_fraction(self) -> np.ndarray:
        """(rows, cols): share of each cell the plan's working width swept."""
        return self.accounts.setting.worked_fraction

    @property
    def limited_fraction(self) -> np.ndarray:
        """(rows, cols): share of each cell covered by product metered at a clipped target."""
        return self.accounts.deposit.limited_coverage

    @property
    def machine_check(self) -> MachineCheck:
        return self.accounts.setting.check

    # The accounts' parts by the names the Python API has documented (README, docs/api.md).
    @property
    def map_metrics(self) -> MapMetrics:
        return self.accounts.map

    @property
    def transition_metrics(self) -> TransitionMetrics:
        return self.accounts.transitions

    @property
    def overlap_metrics(self) -> OverlapMetrics:
        return self.accounts.overlap

    @property
    def limit_metrics(self) -> LimitMetrics:
        return self.accounts.limits

    @property
    def stage_s(self) -> dict:
        return self.accounts.timing.stage_s

    def tick_columns(self) -> dict[str, np.ndarray]:
        """Every per-tick array under one name each, units in the names (`services.sim.ticks.
        tick_columns` lists them); a `VrsimError` for a run accounted part by part (``bounded``)."""
        return ticks.tick_columns(self)

    def to_pandas(self):
        """The per-tick table: a `pandas.DataFrame`, one row per tick (index ``tick``), the columns of
        `tick_columns`. NaN rates: see the class docstring."""
        return ticks.to_pandas(self)
