"""The scenario as run, and a run's summary with the settings it ran with (`with_settings`).

Resolving a scenario's defaults to the values the run uses (`as_run`, `resolved_controller`) is
`services.sim.resolve`, below world building (`services.sim.world.build_world` calls it); this module
re-exports it beside `with_settings`, which reads a finished run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vrsim.services.sim.display import displayed
from vrsim.services.sim.resolve import SENSOR_DELAY_KEYS, as_run, config_as_run, resolved_controller

if TYPE_CHECKING:
    from vrsim.services.sim.run import RunResult

__all__ = ["SENSOR_DELAY_KEYS", "as_run", "resolved_controller", "with_settings"]


def with_settings(result: RunResult) -> dict:
    """A run's summary and, under ``scenario_config``, the settings it ran with: its scenario as run
    with the plant as run (`services.sim.resolve.config_as_run`), and under ``display`` each figure as shown
    in the run's ``units`` (`services.sim.display.displayed`: ``{key: {"value", "unit"}}``). What
    summary.json, ``vrsim run --json``, ``vrsim report --json``, the monitor's report and each run of
    ``vrsim compare --json`` print."""
    return dict(result.summary, display=displayed(result.summary),
                scenario_config=config_as_run(result.world.scenario))
