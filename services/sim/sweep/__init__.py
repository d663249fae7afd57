"""Sweeps: many runs of base scenarios over axes of dotted keys, a design and seeds.

No cluster and no files written here, and all of it pure and deterministic but the task. Three
modules, three ideas: `design` reads and checks a sweep file (`load_sweep`) and expands it into
`RunSpec` s (`plan`: plain data, one per run, each keyed by a hash of its resolved scenario);
`tasks` runs them (`run_row`: one spec, one result row; `run_group`: controller variants over one
drive); `stats` holds the statistics of the sweep's report (`configurations`, `mean_ci95`, `best`,
`pareto_front`). `services.batch` runs the specs on Dask; `services.outputs.sweep_results` and
`services.outputs.sweep_report` write the table and the report.

A sweep file (see ``scenarios/README.md``)::

    scenarios = ["my_field.toml", "default"]   # files (relative to this file) or built-in names
    seeds = [1, 2, 3]                          # each combination runs once per seed
    design = "grid"                            # grid | random | lhs (random and lhs take samples = N)
    [axes]
    "controller.kp" = [0.4, 0.6, 0.8]
    "implement.delivery_delay_s" = { min = 0.4, max = 1.6, n = 4 }
    [set]                                      # the same in every run (not a column)
    "controller.gains" = "manual"
    [report]
    pareto = ["within_10pct_area_pct", "transition_distance_m_mean"]
"""

from vrsim.services.sim.sweep.design import RunSpec, Sweep, load_sweep, parse_sweep, plan, planned_runs
from vrsim.services.sim.sweep.stats import (
    METRIC_SENSE,
    Configuration,
    best,
    configurations,
    mean_ci95,
    pareto_front,
)
from vrsim.services.sim.sweep.tasks import (
    ROW_FIRST,
    ROW_LAST,
    controller_only,
    failed_row,
    run_group,
    run_row,
    variant_groups,
)

__all__ = [
    "RunSpec", "Sweep", "load_sweep", "parse_sweep", "plan", "planned_runs",
    "METRIC_SENSE", "Configuration", "best", "configurations", "mean_ci95", "pareto_front",
    "ROW_FIRST", "ROW_LAST", "controller_only", "failed_row", "run_group", "run_row", "variant_groups",
]
