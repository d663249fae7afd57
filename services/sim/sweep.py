"""Sweeps: many runs of base scenarios over axes of dotted keys, a design and seeds.

No cluster and no files written here, and all of it pure and deterministic but the task.
`load_sweep` reads and checks a sweep file,
`plan` expands it into `RunSpec` s (plain data, one per run, each keyed by a hash of its resolved
scenario), `run_row` is the task that runs one spec and returns one result row, and
`configurations`, `mean_ci95`, `best` and `pareto_front` are the statistics of the sweep's report.
`services.batch` runs the specs on Dask; `services.outputs.sweep_results` and
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

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import os
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from common import ScenarioError, VrsimError
from services.sim import scenario as scenario_mod
from services.sim.metrics import METRICS
from services.sim.overrides import key_parts
from services.sim.tables import no_unknown, typed  # the scenario loader's own checks and messages

SWEEP_KEYS = ("scenarios", "seeds", "design", "samples", "design_seed", "set", "axes", "report")
RANGE_KEYS = ("min", "max", "n", "log")
REPORT_KEYS = ("pareto",)
ROW_FIRST = ("key", "scenario", "seed")  # then one column per axis, then the run's numeric figures
ROW_LAST = ("wall_s", "status", "error")
# A group of controller variants is cut into parts (one task each) of at least this many: each part
# drives once (about 2 s on the default scenario), which this many variants outweigh.
MIN_PART_VARIANTS = 64

# Which way is better ("min", "max" or "zero"), for the accuracy figures the report ranks: the
# METRICS table's sense.
METRIC_SENSE = {m.key: m.sense for m in METRICS if m.sense is not None}


@dataclass(frozen=True)
class Axis:
    """One swept key: discrete `values` (a list, or a range with `n`), or a continuous range
    [`low`, `high`] (random and lhs designs only), log-spaced if `log`, whole numbers if `integer`."""

    key: str
    values: tuple | None = None
    low: float | None = None
    high: float | None = None
    log: bool = False
    integer: bool = False

    def at(self, u: np.ndarray) -> list:
        """The axis values at uniform numbers `u` in [0, 1): a stratum of the values, or a point of
        the range (uniform, or uniform in log if `log`)."""
        if self.values is not None:
            k = len(self.values)
            return [self.values[min(int(x * k), k - 1)] for x in u]
        if self.integer and not self.log:  # every whole number in [low, high] equally likely
            return [int(min(self.low + math.floor(x * (self.high - self.low + 1)), self.high)) for x in u]
        if self.log:
            points = np.exp(np.log(self.low) + u * (np.log(self.high) - np.log(self.low)))
        else:
            points = self.low + u * (self.high - self.low)
        return [int(round(p)) for p in points] if self.integer else [float(p) for p in points]


@dataclass(frozen=True)
class BaseScenario:
    """A scenario a sweep starts from: `label` as written in the sweep file, and what
    `scenario.parse` needs (the text travels with each run, so a remote worker runs what was planned)."""

    label: str
    text: str
    source: str
    base_dir: str


@dataclass(frozen=True)
class Sweep:
    source: str
    scenarios: tuple[BaseScenario, ...]
    seeds: tuple[int, ...] | None  # None: each scenario's own seed
    design: str
    samples: int | None
    design_seed: int
    fixed: tuple[tuple[str, Any], ...]  # [set]: (dotted key, value) set in every run
    axes: tuple[Axis, ...]
    pareto: tuple[str, str] | None


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep, as plain data: the base scenario's text, the axis values and the seed.

    `key` is a hash of the resolved scenario (every key after the overrides and defaults), so the
    same run has the same key in any sweep and ``--resume`` can tell what is done."""

    key: str
    scenario: str  # the base scenario's label
    seed: int
    axes: tuple[tuple[str, Any], ...]  # (dotted key, value), in the sweep file's axis order
    text: str
    source: str
    base_dir: str
    fixed: tuple[tuple[str, Any], ...] = ()  # the sweep's [set], the same in every run

    def overrides(self) -> list[tuple[str, Any]]:
        return [*self.fixed, *self.axes, ("seed", self.seed)]

    def load(self) -> scenario_mod.Scenario:
        return scenario_mod.parse(self.text, self.source, self.base_dir, self.overrides())


# ---------------------------------------------------------------------------------------------------
# The sweep file


def load_sweep(path: str) -> Sweep:
    """Read and check a sweep file; every error names the file, key and value (`ScenarioError`)."""
    try:
        with open(path, "rb") as fh:
            text = fh.read().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read the sweep file: {exc}") from None
    return parse_sweep(text, path, os.path.dirname(os.path.abspath(path)))


def parse_sweep(text: str, source: str = "<sweep>", base_dir: str = ".") -> Sweep:
    """Check a sweep file's TOML text; scenario files in it are relative to `base_dir`."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from None
    no_unknown(doc, SWEEP_KEYS, source, "")
    design = typed(doc, "design", str, source, "", default="grid")
    if design not in DESIGNS:
        raise ScenarioError(f"{source}: design must be one of {', '.join(DESIGNS)}, got {design!r}")
    samples = typed(doc, "samples", int, source, "")
    if design == "grid" and samples is not None:
        raise ScenarioError(f"{source}: samples is for design random or lhs (design is 'grid'), "
                            f"got {samples!r}")
    if design != "grid" and (samples is None or samples < 1):
        raise ScenarioError(f"{source}: design {design!r} needs samples = N >= 1, got {samples!r}")
    axes = _axes(typed(doc, "axes", dict, source, "", default={}), source, design)
    if design != "grid" and not axes:
        raise ScenarioError(f"{source}: design {design!r} needs at least one axis in [axes]")
    fixed = tuple(_flatten(typed(doc, "set", dict, source, "", default={}), ranges=False).items())
    for key, _ in fixed:
        key_parts(key, f"{source}: [set] {key!r}")
        if key in {a.key for a in axes}:
            raise ScenarioError(f"{source}: [set] {key!r} is also an axis; set it in one place")
    return Sweep(source=source, scenarios=_scenarios(doc, source, base_dir), seeds=_seeds(doc, source),
                 design=design, samples=samples,
                 design_seed=typed(doc, "design_seed", int, source, "", default=0), fixed=fixed,
                 axes=axes, pareto=_pareto(typed(doc, "report", dict, source, "", default={}), source))


def _scenarios(doc: dict, source: str, base_dir: str) -> tuple[BaseScenario, ...]:
    names = doc.get("scenarios")
    if isinstance(names, str):
        names = [names]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ScenarioError(f"{source}: scenarios must be a non-empty list of scenario files or built-in "
                            f"names, got {names!r}")
    if len(set(names)) < len(names):
        raise ScenarioError(f"{source}: scenarios lists a scenario twice: {names!r}")
    out = []
    for name in names:
        path = os.path.join(base_dir, name)
        if not os.path.isfile(path) and name not in scenario_mod.builtin_names():
            raise ScenarioError(f"{source}: scenarios: {name!r}: no such file in {base_dir} and no "
                                f"built-in scenario of that name ({', '.join(scenario_mod.builtin_names())})")
        text, src, folder = scenario_mod.read(path if os.path.isfile(path) else name)
        out.append(BaseScenario(label=name, text=text, source=src, base_dir=folder))
    return tuple(out)


def _seeds(doc: dict, source: str) -> tuple[int, ...] | None:
    if "seeds" not in doc:
        return None
    seeds = doc["seeds"]
    if not isinstance(seeds, list) or not seeds or not all(
            isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
        raise ScenarioError(f"{source}: seeds must be a non-empty list of integers >= 0, got {seeds!r}")
    if len(set(seeds)) < len(seeds):
        raise ScenarioError(f"{source}: seeds lists a seed twice: {seeds!r}")
    return tuple(seeds)


def _flatten(table: dict, prefix: str = "", ranges: bool = True) -> dict[str, Any]:
    """``[axes]`` or ``[set]`` as {dotted key: value}: a quoted key ``"controller.kp"`` and a nested
    table ``controller.kp`` (unquoted) mean the same; in ``[axes]`` (`ranges`) a table with ``min``
    or ``max`` is a range, not a nesting."""
    out = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict) and value and not (ranges and {"min", "max"} & set(value)):
            out.update(_flatten(value, dotted + ".", ranges))
        else:
            out[dotted] = value
    return out


def _axes(table: dict, source: str, design: str) -> tuple[Axis, ...]:
    axes = []
    for key, spec in _flatten(table).items():
        where = f"{source}: [axes] {key!r}"
        key_parts(key, where)
        if key == "seed":
            raise ScenarioError(f"{where}: the seed is not an axis; use seeds = [...]")
        if isinstance(spec, list):
            axes.append(_list_axis(key, spec, where))
        elif isinstance(spec, dict):
            axes.append(_range_axis(key, spec, where, design))
        else:
            raise ScenarioError(f"{where} must be a list of values or a range {{min, max, n, log}}, "
                                f"got {spec!r}")
    return tuple(axes)


def _list_axis(key: str, values: list, where: str) -> Axis:
    if not values:
        raise ScenarioError(f"{where}: empty list: an axis needs at least one value")
    if any(isinstance(v, (list, dict)) for v in values):
        raise ScenarioError(f"{where}: values must be numbers, strings or booleans (sweep a table's keys "
                            f"one by one, e.g. map.params.mean_kg_ha), got {values!r}")
    kinds = {"number" if isinstance(v, (int, float)) and not isinstance(v, bool) else type(v).__name__
             for v in values}
    if len(kinds) > 1:
        raise ScenarioError(f"{where}: values must be of one kind (one column of the results), "
                            f"got {values!r}")
    return Axis(key, values=tuple(dict.fromkeys(values)))


def _range_axis(key: str, spec: dict, where: str, design: str) -> Axis:
    unknown = sorted(set(spec) - set(RANGE_KEYS))
    if unknown:
        raise ScenarioError(f"{where}: unknown range key {unknown[0]!r} (known: {', '.join(RANGE_KEYS)})")
    bounds = {}
    for name in ("min", "max"):
        value = spec.get(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ScenarioError(f"{where}: range {name} must be a finite number, got {value!r}")
        bounds[name] = value
    low, high = bounds["min"], bounds["max"]
    if low > high:
        raise ScenarioError(f"{where}: range min must be <= max, got min = {low!r}, max = {high!r}")
    log = spec.get("log", False)
    if not isinstance(log, bool):
        raise ScenarioError(f"{where}: range log must be true or false, got {log!r}")
    if log and low <= 0:
        raise ScenarioError(f"{where}: a log range needs min > 0, got min = {low!r}")
    integer = isinstance(low, int) and isinstance(high, int)
    n = spec.get("n")
    if n is None:
        if design == "grid":
            raise ScenarioError(f"{where}: a range in a grid design needs n (how many values)")
        return Axis(key, low=low, high=high, log=log, integer=integer)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ScenarioError(f"{where}: range n must be an integer >= 1, got {n!r}")
    points = (np.geomspace if log else np.linspace)(low, high, n)
    values = [int(round(p)) for p in points] if integer else [float(p) for p in points]
    return Axis(key, values=tuple(dict.fromkeys(values)), log=log, integer=integer)


def _pareto(report: dict, source: str) -> tuple[str, str] | None:
    no_unknown(report, REPORT_KEYS, source, "report")
    if "pareto" not in report:
        return None
    pair = report["pareto"]
    if not (isinstance(pair, list) and len(pair) == 2 and all(m in METRIC_SENSE for m in pair)
            and pair[0] != pair[1]):
        raise ScenarioError(f"{source}: [report] pareto must be two different metrics of "
                            f"{', '.join(METRIC_SENSE)}, got {pair!r}")
    return tuple(pair)


# ---------------------------------------------------------------------------------------------------
# The design and the plan


def grid_points(axes: Sequence[Axis], samples: int | None, rng: np.random.Generator) -> list[tuple]:
    """Every combination of the axes' values (one point, of no values, without axes)."""
    return list(itertools.product(*(a.values for a in axes)))


def random_points(axes: Sequence[Axis], samples: int, rng: np.random.Generator) -> list[tuple]:
    """`samples` points, each axis drawn independently and uniformly."""
    return _points(axes, rng.random((samples, len(axes))))


def lhs_points(axes: Sequence[Axis], samples: int, rng: np.random.Generator) -> list[tuple]:
    """`samples` points of a Latin hypercube: each axis's range cut into `samples` equal strata, each
    stratum used once (scipy's `LatinHypercube`)."""
    from scipy.stats import qmc

    return _points(axes, qmc.LatinHypercube(d=len(axes), seed=rng).random(samples))


def _points(axes: Sequence[Axis], u: np.ndarray) -> list[tuple]:
    columns = [axis.at(u[:, j]) for j, axis in enumerate(axes)]
    return list(zip(*columns, strict=True))


# The designs a sweep file may name: (axes, samples, rng) -> points, one value per axis each.
DESIGNS: dict[str, Callable[[Sequence[Axis], int | None, np.random.Generator], list[tuple]]] = {
    "grid": grid_points, "random": random_points, "lhs": lhs_points,
}


def design_points(sweep: Sweep) -> list[tuple]:
    """The design's points (one value per axis, in axis order), deterministic for a `design_seed`."""
    rng = np.random.default_rng(sweep.design_seed)
    return DESIGNS[sweep.design](sweep.axes, sweep.samples, rng)


def scenario_key(sc: scenario_mod.Scenario) -> str:
    """A hash of a resolved scenario: every value after overrides and defaults (not the file's name
    or path, which do not change what runs; the folder relative paths resolve against does)."""
    doc = scenario_mod.as_dict(sc)
    doc.pop("source")
    text = json.dumps(doc, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def plan(sweep: Sweep) -> list[RunSpec]:
    """Every run of the sweep, each checked like a scenario file; runs that resolve to the same
    scenario (a design drawing the same point twice) are planned once.

    Raises
    ------
    ScenarioError
        A combination the scenario loader refuses, naming the sweep file, the scenario, the axis
        values and the loader's message (file, table, key, value).
    """
    keys = [a.key for a in sweep.axes]
    points = design_points(sweep)
    specs: dict[str, RunSpec] = {}
    for base in sweep.scenarios:
        _check_range_ends(sweep, base, points[0] if points else ())
        for point in points:
            values = tuple(zip(keys, point, strict=True))
            for seed in sweep.seeds or (None,):
                overrides = [*sweep.fixed, *values, *([("seed", seed)] if seed is not None else [])]
                sc = _checked(sweep, base, overrides)
                spec = RunSpec(key=scenario_key(sc), scenario=base.label, seed=sc.seed, axes=values,
                               text=base.text, source=base.source, base_dir=base.base_dir,
                               fixed=sweep.fixed)
                specs.setdefault(spec.key, spec)
    return list(specs.values())


def _check_range_ends(sweep: Sweep, base: BaseScenario, point: tuple) -> None:
    """Both ends of each continuous range, in the first point, so a bad bound fails before the run
    (a random design need not draw near it)."""
    for j, axis in enumerate(sweep.axes):
        if axis.values is None:
            for end in (axis.low, axis.high):
                values = [(a.key, v) for a, v in zip(sweep.axes, point, strict=True)]
                values[j] = (axis.key, end)
                _checked(sweep, base, [*sweep.fixed, *values])


def _checked(sweep: Sweep, base: BaseScenario, overrides: list) -> scenario_mod.Scenario:
    try:
        return scenario_mod.parse(base.text, base.source, base.base_dir, overrides)
    except ScenarioError as exc:
        combo = ", ".join(f"{k} = {v!r}" for k, v in overrides) or "no overrides"
        raise ScenarioError(f"{sweep.source}: scenario {base.label!r} with {combo}: {exc}") from None


# ---------------------------------------------------------------------------------------------------
# The task: one run, one row


def numeric_figures(summary: dict) -> dict[str, float | int | None]:
    """The numbers of a run's summary (`vrsim run --json` keys whose value is a number; a non-finite
    figure is None, as ``null`` there)."""
    out = {}
    for key, value in summary.items():
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
            value = value.item() if isinstance(value, np.generic) else value
            out[key] = value if math.isfinite(value) else None
    return out


def identity(spec: RunSpec) -> dict:
    """The columns that say which run a row is: key, scenario, seed and one per axis."""
    return {"key": spec.key, "scenario": spec.scenario, "seed": spec.seed, **dict(spec.axes)}


def failed_row(spec: RunSpec, error: str, wall_s: float | None = None) -> dict:
    return {**identity(spec), "wall_s": wall_s, "status": "failed", "error": error}


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
        `identity`, the run's `numeric_figures`, ``wall_s`` (this task's wall time, s), ``status``
        (``"ok"`` or ``"failed"``) and ``error`` (None, or the message).
    """
    from services.sim import run as field_run  # imports SUMO: only where a run happens

    t0 = time.perf_counter()
    try:
        result = field_run.run(spec.load())
        if after is not None:
            after(spec, result)
    except VrsimError as exc:
        return failed_row(spec, str(exc), time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - one run's bug is that run's failed row, not the sweep's end
        return failed_row(spec, f"internal error: {type(exc).__name__}: {exc}", time.perf_counter() - t0)
    figures = numeric_figures(result.summary)
    return {**identity(spec), **figures, "wall_s": time.perf_counter() - t0, "status": "ok", "error": None}


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
    from services.sim.run import drive
    from services.sim.variants import run_variants

    t0 = time.perf_counter()
    try:
        scenarios = [spec.load() for spec in specs]
        summaries = run_variants(drive(scenarios[0]), [sc.controller for sc in scenarios])
    except Exception:  # noqa: BLE001 - each run on its own then says which one failed, and why
        return [run_row(spec) for spec in specs]
    wall_s = (time.perf_counter() - t0) / len(specs)
    return [{**identity(spec), **numeric_figures(summary), "wall_s": wall_s, "status": "ok", "error": None}
            for spec, summary in zip(specs, summaries, strict=True)]


# ---------------------------------------------------------------------------------------------------
# Statistics for the report


@dataclass
class Configuration:
    """The ok runs of one scenario at one point of the design (its seeds are the replicates)."""

    scenario: str
    axes: tuple[tuple[str, Any], ...]
    rows: list[dict] = dataclasses.field(default_factory=list)

    def values(self, metric: str) -> np.ndarray:
        got = [r.get(metric) for r in self.rows]
        return np.array([v for v in got if v is not None and math.isfinite(v)], dtype=float)

    def label(self) -> str:
        return ", ".join([self.scenario, *(f"{k}={v}" for k, v in self.axes)])


def configurations(rows: Sequence[dict], axis_keys: Sequence[str]) -> list[Configuration]:
    """The ok rows grouped by scenario and axis values, in first-seen order."""
    groups: dict[tuple, Configuration] = {}
    for row in rows:
        if row.get("status") != "ok":
            continue
        axes = tuple((k, row.get(k)) for k in axis_keys)
        groups.setdefault((row["scenario"], axes), Configuration(row["scenario"], axes)).rows.append(row)
    return list(groups.values())


def mean_ci95(values: np.ndarray) -> tuple[float, float]:
    """Mean and the half-width of its 95 % confidence interval (Student's t over the replicates;
    NaN half-width for fewer than two, NaN mean for none)."""
    from scipy import stats

    n = len(values)
    if n == 0:
        return math.nan, math.nan
    mean = float(np.mean(values))
    if n < 2:
        return mean, math.nan
    return mean, float(stats.t.ppf(0.975, n - 1) * np.std(values, ddof=1) / math.sqrt(n))


def badness(metric: str, value: np.ndarray | float):
    """Smaller is better: the metric's value turned by its `METRIC_SENSE`."""
    sense = METRIC_SENSE[metric]
    return -value if sense == "max" else (np.abs(value) if sense == "zero" else value)


def best(configs: Sequence[Configuration], metric: str, k: int = 3):
    """The `k` best configurations by their mean `metric`: [(configuration, mean, ci95 half-width)]."""
    scored = [(c, *mean_ci95(c.values(metric))) for c in configs]
    scored = [s for s in scored if math.isfinite(s[1])]
    return sorted(scored, key=lambda s: badness(metric, s[1]))[:k]


def pareto_front(x: np.ndarray, y: np.ndarray, metric_x: str, metric_y: str) -> np.ndarray:
    """Boolean mask of the points no other point beats on both metrics (at least as good on both and
    better on one), each metric turned by its sense; NaN points are never on the front."""
    bx, by = badness(metric_x, np.asarray(x, float)), badness(metric_y, np.asarray(y, float))
    ok = np.isfinite(bx) & np.isfinite(by)
    no_worse = (bx[None, :] <= bx[:, None]) & (by[None, :] <= by[:, None]) & ok[None, :]
    better = (bx[None, :] < bx[:, None]) | (by[None, :] < by[:, None])
    return ok & ~(no_worse & better).any(axis=1)
