"""A sweep's plan: the sweep file read and checked, its design's points, one `RunSpec` per run.

Pure and deterministic: a run's scenario is resolved (and checked, each error naming the sweep
file, the scenario, the axis values and the loader's message) when it is planned, not when it runs.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vrsim.common import ScenarioError, files
from vrsim.common.toml_text import loads_toml
from vrsim.services.sim import scenario as scenario_mod
from vrsim.services.sim.overrides import key_parts, machine_overrides
from vrsim.services.sim.scenario_toml import as_dict
from vrsim.services.sim.sweep.stats import METRIC_SENSE
from vrsim.services.sim.tables import no_unknown, typed  # the scenario loader's own checks and messages

SWEEP_KEYS = ("scenarios", "seeds", "design", "samples", "design_seed", "machine", "set", "axes", "report")
RANGE_KEYS = ("min", "max", "n", "log")
REPORT_KEYS = ("pareto",)


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
    data = files.read_bytes(path, "toml", ScenarioError)  # a regular file within the TOML cap
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: cannot read the sweep file: {exc}") from None
    return parse_sweep(text, path, os.path.dirname(os.path.abspath(path)))


def parse_sweep(text: str, source: str = "<sweep>", base_dir: str = ".") -> Sweep:
    """Check a sweep file's TOML text; scenario files in it are relative to `base_dir`."""
    try:
        doc = loads_toml(text, f"{source}: not a sweep file", ScenarioError)
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
    machine = typed(doc, "machine", str, source, "")
    if machine is not None:   # a machine file's keys (machine_fit.toml); [set] and the axes over them
        fixed = (*machine_overrides(os.path.join(base_dir, machine)), *fixed)
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


def _grid_points(axes: Sequence[Axis], samples: int | None, rng: np.random.Generator) -> list[tuple]:
    """Every combination of the axes' values (one point, of no values, without axes)."""
    return list(itertools.product(*(a.values for a in axes)))


def _random_points(axes: Sequence[Axis], samples: int, rng: np.random.Generator) -> list[tuple]:
    """`samples` points, each axis drawn independently and uniformly."""
    return _points(axes, rng.random((samples, len(axes))))


def _lhs_points(axes: Sequence[Axis], samples: int, rng: np.random.Generator) -> list[tuple]:
    """`samples` points of a Latin hypercube: each axis's range cut into `samples` equal strata, each
    stratum used once (scipy's `LatinHypercube`)."""
    from scipy.stats import qmc

    return _points(axes, qmc.LatinHypercube(d=len(axes), seed=rng).random(samples))


def _points(axes: Sequence[Axis], u: np.ndarray) -> list[tuple]:
    columns = [axis.at(u[:, j]) for j, axis in enumerate(axes)]
    return list(zip(*columns, strict=True))


# The designs a sweep file may name: (axes, samples, rng) -> points, one value per axis each.
DESIGNS: dict[str, Callable[[Sequence[Axis], int | None, np.random.Generator], list[tuple]]] = {
    "grid": _grid_points, "random": _random_points, "lhs": _lhs_points,
}


def _design_points(sweep: Sweep) -> list[tuple]:
    """The design's points (one value per axis, in axis order), deterministic for a `design_seed`."""
    rng = np.random.default_rng(sweep.design_seed)
    return DESIGNS[sweep.design](sweep.axes, sweep.samples, rng)


def _scenario_key(sc: scenario_mod.Scenario) -> str:
    """A hash of a resolved scenario: every value after overrides and defaults (not the file's name
    or path, which do not change what runs; the folder relative paths resolve against does)."""
    doc = as_dict(sc)
    doc.pop("source")
    text = json.dumps(doc, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def planned_runs(sweep: Sweep) -> int:
    """How many runs `plan` makes at most (before runs that resolve to the same scenario are merged),
    counted without planning them: a big sweep's size, told before the seconds its plan takes."""
    points = math.prod(len(a.values) for a in sweep.axes) if sweep.design == "grid" else sweep.samples
    return points * len(sweep.scenarios) * len(sweep.seeds or (None,))


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
    points = _design_points(sweep)
    specs: dict[str, RunSpec] = {}
    for base in sweep.scenarios:
        _check_range_ends(sweep, base, points[0] if points else ())
        for point in points:
            values = tuple(zip(keys, point, strict=True))
            for seed in sweep.seeds or (None,):
                overrides = [*sweep.fixed, *values, *([("seed", seed)] if seed is not None else [])]
                sc = _checked(sweep, base, overrides)
                spec = RunSpec(key=_scenario_key(sc), scenario=base.label, seed=sc.seed, axes=values,
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
