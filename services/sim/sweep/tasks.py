"""A sweep's tasks: one run, one result row (`run_row`), and controller variants over one drive as one
batch (`run_group`, the fast path), with how a sweep's runs are cut into such groups.

The only part of a sweep that runs the simulation (and imports SUMO, lazily: where a run happens).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from vrsim.common import VrsimError
from vrsim.services.sim.sweep.design import RunSpec, Sweep

ROW_FIRST = ("key", "scenario", "seed")  # then one column per axis, then the run's numeric figures
ROW_LAST = ("wall_s", "status", "error")
# A group of controller variants is cut into parts (one task each) of at least this many: each part
# drives once (about 2 s on the default scenario), which this many variants outweigh.
MIN_PART_VARIANTS = 64



def _numeric_figures(summary: dict) -> dict[str, float | int | None]:
    """The numbers of a run's summary (`vrsim run --json` keys whose value is a number; a non-finite
    figure is None, as ``null`` there)."""
    out = {}
    for key, value in summary.items():
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
            value = value.item() if isinstance(value, np.generic) else value
            out[key] = value if math.isfinite(value) else None
    return out


def _figures(summary: dict) -> dict:
    """`_numeric_figures`, the rate figures in the map's own unit (``mae_in_rate_unit``, ... from the
    summary's ``in_rate_unit``) and that unit (``rate_unit``): what the sweep's report shows."""
    own = _numeric_figures(summary.get("in_rate_unit", {}))
    return {**_numeric_figures(summary), **{f"{k}_in_rate_unit": v for k, v in own.items()},
            "rate_unit": summary.get("rate_unit")}


def _identity(spec: RunSpec) -> dict:
    """The columns that say which run a row is: key, scenario, seed and one per axis."""
    return {"key": spec.key, "scenario": spec.scenario, "seed": spec.seed, **dict(spec.axes)}


def failed_row(spec: RunSpec, error: str, wall_s: float | None = None, lost: bool = False) -> dict:
    """The row of a run without figures: ``status`` ``"failed"`` (the run itself failed: it would
    again) or, with `lost`, ``"lost"`` (the cluster dropped it: ``--resume`` runs it again)."""
    return {**_identity(spec), "wall_s": wall_s, "status": "lost" if lost else "failed", "error": error}


def run_row(spec: RunSpec, after: Callable | None = None) -> dict:
    """Run one spec in this process and return its row; never raises for a run that fails.

    Parameters
    ----------
    spec : RunSpec
    after : callable, optional
        ``after(spec, result)`` runs after a successful run (e.g. writing its output files); it may add
        figures to ``result.summary``; what it raises fails the row.

    Returns
    -------
    dict
        `_identity`, the run's `_figures`, ``wall_s`` (this task's wall time, s), ``status``
        (``"ok"`` or ``"failed"``) and ``error`` (None, or the message).
    """
    from vrsim.services.sim.run import run  # imports SUMO: only where a run happens

    t0 = time.perf_counter()
    try:
        result = run(spec.load())
        if after is not None:
            after(spec, result)
    except VrsimError as exc:
        return failed_row(spec, str(exc), time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - one run's bug is that run's failed row, not the sweep's end
        return failed_row(spec, f"internal error: {type(exc).__name__}: {exc}", time.perf_counter() - t0)
    figures = _figures(result.summary)
    return {**_identity(spec), **figures, "wall_s": time.perf_counter() - t0, "status": "ok", "error": None}


def controller_only(sweep: Sweep) -> bool:
    """True if every axis is a ``controller.*`` key: the runs of one scenario and seed then share
    their drive and can take the batched fast path (`run_group`)."""
    return bool(sweep.axes) and all(a.key.startswith("controller.") for a in sweep.axes)


def variant_groups(specs: Sequence[RunSpec], workers: int = 1,
                   min_part: int = MIN_PART_VARIANTS) -> list[tuple[RunSpec, ...]]:
    """The specs grouped by base scenario and seed, in first-seen order (one drive per group), each
    group cut into consecutive parts of about equal size when there are fewer groups than `workers`:
    as many parts as it takes for every worker to have one, each of at least `min_part` specs.

    Each part is its own `run_group` task and drives on its own: with a core per worker the parts'
    drives run side by side, so the wall time is one drive plus a part's variants, as when one drive
    is shipped to every worker, without a task that waits for another or a drive in transit.
    """
    groups: dict[tuple[str, int], list[RunSpec]] = {}
    for spec in specs:
        groups.setdefault((spec.scenario, spec.seed), []).append(spec)
    wanted = -(-workers // max(len(groups), 1))   # parts per group for every worker to have one
    parts = []
    for group in groups.values():
        k = max(1, min(wanted, len(group) // max(min_part, 1)))
        bounds = [len(group) * i // k for i in range(k + 1)]
        parts += [tuple(group[lo:hi]) for lo, hi in itertools.pairwise(bounds)]
    return parts


def run_group(specs: Sequence[RunSpec]) -> list[dict]:
    """The rows of specs that differ only in ``controller.*`` keys (a group or a part of one, from
    `variant_groups`), through the fast path: one drive, then all controllers as one batch
    (`services.sim.variants.run_variants`).

    Rows have the form of `run_row`'s, ``wall_s`` each run's share of the group's wall time. If the
    batch fails (a controller the run refuses), every spec runs alone through `run_row`, so a failed
    row is that run's own, with its own message.
    """
    from vrsim.services.sim.run import drive
    from vrsim.services.sim.variants import run_variants

    t0 = time.perf_counter()
    try:
        scenarios = [spec.load() for spec in specs]
        summaries = run_variants(drive(scenarios[0]), [sc.controller for sc in scenarios])
    except Exception:  # noqa: BLE001 - each run on its own then says which one failed, and why
        return [run_row(spec) for spec in specs]
    wall_s = (time.perf_counter() - t0) / len(specs)
    return [{**_identity(spec), **_figures(summary), "wall_s": wall_s, "status": "ok", "error": None}
            for spec, summary in zip(specs, summaries, strict=True)]
