"""`vrsim tune`: search a controller's parameters for the best figure on one field.

Any controller: the scenario's own (``[controller]``, a user's ``python`` class included), a kind with
its defaults, or a controller spec file (a TOML with a ``[controller]`` table, as `vrsim compare`
takes: `services.sim.compare.resolve_spec`).

scipy's `differential_evolution` with ``vectorized=True`` and ``updating="deferred"`` proposes a whole
population at a time; every population is one batch of controller variants over one shared drive
(`services.sim.variants.run_variants`: the PID family on its lifted-matrix fast path with gains per
loop, every other kind one loop after another, which is all a kind that cannot batch can do). The objective
is a figure of `METRICS` with a sense (``min``, ``max`` or ``zero``: its magnitude is minimised), a
figure that does not exist for a candidate (no rate step settled) counts as the worst.

Budget: about `budget` evaluations in whole generations: a population of ``max(5, m x params)``
candidates (m from 1 to 15, so that about six generations fit), evaluated ``budget // population``
times (at least once); the search may stop earlier when the population has converged (scipy's
``tol``).

The objective knows nothing of stability: the best figure may come from gains at the edge of it. So
the result holds the tuned loop's and the scenario's own loop's margins (`services.sim.analyze.loop_of`:
python-control's `stability_margins` on the loop `vrsim controller analyze` builds, the machine's own
plant), and a warning when the tuned loop's are below 6 dB or 45 deg (`TuneResult.margin_warning`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError, ScenarioError
from vrsim.controller import ControllerConfig, PlantParams, build_controller
from vrsim.controller.analysis import LoopAnalysis
from vrsim.controller.config import PID_KINDS, USER_KIND
from vrsim.services.sim.analyze import loop_of, margin_warning
from vrsim.services.sim.as_run import resolved_controller
from vrsim.services.sim.compare import resolve_spec
from vrsim.services.sim.core import machine_plant, plant_for
from vrsim.services.sim.metrics import METRICS
from vrsim.services.sim.run import drive as drive_of
from vrsim.services.sim.scenario import KIND_INDEPENDENT_KEYS, Scenario
from vrsim.services.sim.variants import run_variants

PID_TUNABLE = ("kp", "ki", "kd")   # the PID family's numeric keys (its gains are then "manual")
TOP_LEVEL = ("look_ahead_s",)      # keys of [controller] itself that any kind can tune
SENSES = {m.key: m.sense for m in METRICS if m.sense is not None}
# On a replayed log (`tune(..., log=...)`): the twin's error against its targets on the log's drive.
LOG_SENSES = {"twin_mae_vs_target": "min"}
GENERATIONS = 6                    # the budget is shared so that about this many generations fit
MAX_POPSIZE = 15                   # scipy's default multiplier


@dataclass(frozen=True)
class TuneParam:
    """One searched parameter: its name in ``[controller]`` (or in its ``params``) and its range."""

    name: str
    low: float
    high: float


@dataclass
class TuneResult:
    scenario: str
    objective: str
    sense: str
    params: tuple[TuneParam, ...]
    best: ControllerConfig
    best_values: dict
    best_objective: float
    evaluations: int
    generations: int
    history: list[dict]      # one row per evaluation: evaluation, generation, params, objective, best
    tuned: dict              # the best controller's summary
    baseline: dict           # the scenario's own controller's summary
    # The loops' margins on the machine's plant (`services.sim.analyze.loop_of`): None for a kind
    # without a linear model, `no_loop_reason` says why.
    tuned_loop: LoopAnalysis | None = None
    baseline_loop: LoopAnalysis | None = None
    no_loop_reason: str = ""

    @property
    def margin_warning(self) -> str | None:
        """Why the tuned loop's margins are too small (`services.sim.analyze.margin_warning`), or None."""
        return margin_warning(self.tuned_loop)


def parse_param(text: str) -> TuneParam:
    """``NAME=LOW:HIGH`` (numbers, LOW < HIGH); `ScenarioError` naming the text otherwise."""
    name, sep, span = text.partition("=")
    low, colon, high = span.partition(":")
    try:
        if not (sep and colon and name.strip()):
            raise ValueError
        lo, hi = float(low), float(high)
    except ValueError:
        raise ScenarioError(f"--param {text!r}: must be NAME=LOW:HIGH (e.g. kp=0.1:2.0)") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo >= hi:
        raise ScenarioError(f"--param {text!r}: LOW must be < HIGH (finite numbers), got {lo:g} and {hi:g}")
    return TuneParam(name.strip(), lo, hi)


def check_objective(metric: str, log: bool = False) -> str:
    """The metric's sense (on a replayed log's drive: `LOG_SENSES`); `ScenarioError` listing the
    figures that have one otherwise."""
    senses = LOG_SENSES if log else SENSES
    if metric not in senses:
        raise ScenarioError(f"--objective {metric!r}: not a figure to optimise"
                            f"{' on a log' if log else ''} (one of {', '.join(senses)})")
    return senses[metric]


def _base_config(scenario: Scenario, controller: str | None = None) -> ControllerConfig:
    """The configuration candidates start from.

    `controller`: None for the scenario's own ``[controller]``; a TOML file with a ``[controller]``
    table (`services.sim.compare.resolve_spec`: its ``file`` relative to that TOML file); or a kind
    with its defaults and the scenario's look-ahead keys. For P, PI and PID the gains become manual
    at the values they resolve to (so an untuned gain keeps them).
    """
    if controller is not None and os.path.isfile(controller):
        cfg = resolve_spec(controller, scenario).config
    elif controller is None:
        cfg = scenario.controller
    else:
        keep = {k: getattr(scenario.controller, k) for k in KIND_INDEPENDENT_KEYS}
        try:
            cfg = ControllerConfig(kind=controller, **keep)
        except ControllerError as exc:
            raise ScenarioError(f"--controller {controller!r}: {exc}") from None
    if cfg.kind not in PID_KINDS:
        return cfg
    try:   # the gains as the run resolves them (`services.sim.as_run`), manual from here on
        return resolved_controller(cfg, plant_for(scenario), scenario.timing.control_period_s)
    except ControllerError as exc:
        raise ScenarioError(f"--controller {controller or cfg.kind!r}: {exc}") from None


def _config_at(base: ControllerConfig, params: Sequence[TuneParam], values) -> ControllerConfig:
    """`base` with each parameter set to its value (`ControllerError` if the kind refuses one)."""
    top, inner = {}, {}
    for p, v in zip(params, values, strict=True):
        (top if p.name in TOP_LEVEL or base.kind in PID_KINDS else inner)[p.name] = float(v)
    if inner:
        top["params"] = {**base.params, **inner}
    return dataclasses.replace(base, **top)


def _check_params(base: ControllerConfig, params: Sequence[TuneParam], scenario: Scenario) -> None:
    """Each parameter is a number the kind takes, at both ends of its range; `ScenarioError` otherwise.

    A user's class (kind ``python``) checks its own params: it is built once at each end.
    """
    timing = scenario.timing
    for p in params:
        if base.kind in PID_KINDS and p.name not in PID_TUNABLE + TOP_LEVEL:
            raise ScenarioError(f"--param {p.name!r}: kind {base.kind!r} tunes "
                                f"{', '.join(PID_TUNABLE + TOP_LEVEL)}")
        if p.name in ("kd", "ki") and base.kind in PID_KINDS and getattr(base, p.name) is None:
            raise ScenarioError(f"--param {p.name!r}: kind {base.kind!r} has no such term")
        for end in (p.low, p.high):
            try:
                cfg = _config_at(base, [p], [end])
                if cfg.kind == USER_KIND:
                    build_controller(cfg, plant_for(scenario), timing.control_period_s, timing.plant_step_s)
            except (ControllerError, TypeError) as exc:
                raise ScenarioError(f"--param {p.name}={p.low:g}:{p.high:g}: kind {base.kind!r}: "
                                    f"{exc}") from None


def _generations_for(budget: int, dims: int) -> tuple[int, int]:
    """(popsize multiplier, scipy's maxiter) for about `budget` evaluations (see the module docstring)."""
    m = int(min(MAX_POPSIZE, max(1, budget // (GENERATIONS * dims))))
    population = max(5, m * dims)
    return m, max(0, budget // population - 1)


def tune(scenario: Scenario, controller: str | None, params: Sequence[TuneParam], objective: str,
         budget: int, seed: int = 0, progress: Callable[[int, float], None] | None = None,
         log=None) -> TuneResult:
    """Search `params` of a controller for the best `objective` on `scenario`'s field, or on the drive of
    a machine's own log (`log`: `maps.log_records.MachineRecords`, replayed with `scenario`'s machine,
    `services.sim.replay`: a controller tuned on the twin of the user's machine).

    Parameters
    ----------
    scenario : Scenario
    controller : str or None
        None: the scenario's own controller; a controller kind (``PID``, ``PI``, ``P``, ``aog_pi``,
        ...) with its defaults; or a TOML file with a ``[controller]`` table (`_base_config`).
    params : sequence of TuneParam
        The searched parameters and their ranges (names as in ``[controller]``, or its ``params`` for
        kinds other than P, PI, PID; ``look_ahead_s`` for any kind).
    objective : str
        A figure of `METRICS` with a sense.
    budget : int
        About how many candidates to evaluate (>= 1).
    seed : int
        Seeds the search (the drive keeps the scenario's seed).
    progress : callable, optional
        ``progress(evaluations, best objective so far)`` after each generation.
    log : maps.log_records.MachineRecords, optional
        The drive to judge candidates on instead of the field's: each one replays the log
        (`LOG_SENSES` are its objectives).

    Raises
    ------
    ScenarioError
        Unknown kind, a spec file that does not load, an unknown parameter or metric, an empty or
        reversed range, a budget below 1.
    """
    from scipy.optimize import differential_evolution

    sense = check_objective(objective, log is not None)
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise ScenarioError(f"--budget must be an integer >= 1, got {budget!r}")
    if not params:
        raise ScenarioError("--param: give at least one parameter to tune (NAME=LOW:HIGH)")
    names = [p.name for p in params]
    if len(set(names)) < len(names):
        raise ScenarioError(f"--param: a parameter is given twice: {names}")
    base = _base_config(scenario, controller)
    _check_params(base, params, scenario)
    if log is not None:
        judge, plant = _replays(log, scenario), _log_plant(log, scenario)
    else:
        shared = drive_of(scenario)
        judge, plant = _field_runs(shared), machine_plant(shared.world.scenario, shared.world.grid)
    history: list[dict] = []
    best = [math.inf]

    def score(summary: dict) -> float:
        value = summary.get(objective)
        if value is None or not math.isfinite(value):
            return math.inf
        return -value if sense == "max" else abs(value) if sense == "zero" else value

    def evaluate(x: np.ndarray) -> np.ndarray:      # x: (params, population)
        columns = np.atleast_2d(x).T
        summaries = judge([_config_at(base, params, v) for v in columns])
        scores = np.array([score(s) for s in summaries])
        generation = 1 + max((h["generation"] for h in history), default=0)
        for v, s, sc in zip(columns, summaries, scores, strict=True):
            best[0] = min(best[0], sc)
            history.append({"evaluation": len(history) + 1, "generation": generation,
                            **{p.name: float(val) for p, val in zip(params, v, strict=True)},
                            objective: s.get(objective), "best_so_far": _unscore(best[0], sense)})
        if progress is not None:
            progress(len(history), _unscore(best[0], sense))
        return scores

    popsize, maxiter = _generations_for(budget, len(params))
    found = differential_evolution(evaluate, [(p.low, p.high) for p in params], popsize=popsize,
                                   maxiter=maxiter, vectorized=True, updating="deferred", polish=False,
                                   rng=np.random.default_rng(seed))
    best_cfg = _config_at(base, params, found.x)
    tuned, baseline = judge([best_cfg, scenario.controller])
    period_s = scenario.timing.control_period_s
    tuned_loop, why = loop_of(plant, best_cfg, period_s)
    return TuneResult(scenario=scenario.name, objective=objective, sense=sense, params=tuple(params),
                      best=best_cfg, best_values=dict(zip(names, map(float, found.x), strict=True)),
                      best_objective=tuned.get(objective), evaluations=len(history),
                      generations=history[-1]["generation"] if history else 0, history=history,
                      tuned=tuned, baseline=baseline, tuned_loop=tuned_loop,
                      baseline_loop=loop_of(plant, scenario.controller, period_s)[0], no_loop_reason=why)


def _field_runs(shared):
    """Candidates judged on the scenario's field: one batch of variants over one shared drive."""
    return lambda configs: run_variants(shared, configs)


def _replays(log, scenario: Scenario):
    """Candidates judged on a machine's log: each replays it with the scenario's machine."""
    from vrsim.services.sim.replay import replay_records

    return lambda configs: [replay_records(log, dataclasses.replace(scenario, controller=c)).summary
                            for c in configs]


def _log_plant(log, scenario: Scenario) -> PlantParams:
    """The plant the machine's loops close on a replay of `log` (`services.sim.replay`): at the log's
    median positive target, as the replay's core sets its working point."""
    from vrsim.maps.units import convert_rate
    from vrsim.services.sim.replay import working_point_grid

    rate_kg_ha = convert_rate(log.target, log.unit or "kg/ha", "kg/ha", scenario.product.density_kg_l)
    return machine_plant(scenario, working_point_grid(log, rate_kg_ha))


def _unscore(score: float, sense: str) -> float | None:
    if not math.isfinite(score):
        return None
    return -score if sense == "max" else score
