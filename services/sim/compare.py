"""Several controllers on one scenario: the same drive (seed, SUMO track, sensor noise), one control
and accounting stage per controller (`vrsim compare`).

A controller *spec* is either the name of a built-in kind (``pid``, ``aog_pi``, ``ff_pi``, ``smith``,
``fuzzy_pid``, ``ideal``; also ``P``, ``PI``, ``PID``) with its default parameters, or the path of a
TOML file with a ``[controller]`` table (any kind, ``python`` included; its ``file`` is taken
relative to that TOML file's folder). Either way the look-ahead keys (``look_ahead_s``,
``look_ahead_tune``) come from the scenario unless the spec sets them, and ``look_ahead`` of
`compare` overrides them for every controller.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass

from vrsim.common import ScenarioError, files
from vrsim.common.toml_text import loads_toml
from vrsim.controller import KINDS, ControllerConfig
from vrsim.controller.config import PID_KINDS
from vrsim.services.sim.as_run import with_settings
from vrsim.services.sim.metrics import METRICS
from vrsim.services.sim.run import Drive, RunResult, control_and_account, drive
from vrsim.services.sim.scenario import KIND_INDEPENDENT_KEYS, Scenario, controller_from_table

USER_KIND = "python"
# Which way is better for each compared figure: "low", "high" or "zero" (smallest magnitude), from the
# METRICS table's sense. Every figure of `METRICS` the accuracy library holds, except the two masses
# (they describe the run, the mass balance judges them).
_WORDS = {"min": "low", "max": "high", "zero": "zero"}
BETTER = {m.key: _WORDS[m.sense] for m in METRICS
          if m.sense is not None and m.tolerance is not None}
COLUMNS = tuple(m for m in METRICS if m.key in BETTER)


def _builtin_specs() -> list[str]:
    """Every built-in kind, the default set of `vrsim compare`: ``pid`` (the paper's PID, the reference)
    first, then the others as registered."""
    return ["pid", *(k for k in KINDS if k not in ("pid", USER_KIND))]


@dataclass(frozen=True)
class ControllerSpec:
    """One compared controller: `label` (the spec as given) and its configuration."""

    label: str
    config: ControllerConfig


def resolve_spec(spec: str, scenario: Scenario, look_ahead=None) -> ControllerSpec:
    """The controller configuration `spec` names for `scenario` (see the module docstring).

    Raises `ScenarioError` naming the spec (and file, key, value) when it is neither a known kind
    nor a readable TOML file with a valid ``[controller]`` table.
    """
    override = {} if look_ahead is None else {"look_ahead_s": look_ahead}
    if not isinstance(spec, str) or not spec:
        raise ScenarioError(f"controller spec must be a kind or a TOML file, got {spec!r}")
    kept = {k: getattr(scenario.controller, k) for k in KIND_INDEPENDENT_KEYS}
    if spec in KINDS or spec in PID_KINDS:
        if spec == USER_KIND:
            raise ScenarioError("controller spec 'python' needs a TOML file with file and class in its "
                                "[controller] table")
        table, source, base = {"kind": spec}, f"controller spec {spec!r}", scenario.base_dir
    elif os.path.isfile(spec):
        table, source, base = _spec_table(spec), spec, os.path.dirname(os.path.abspath(spec))
    else:
        known = ", ".join([*_builtin_specs(), "P", "PI", "PID"])
        raise ScenarioError(f"controller spec {spec!r}: neither a kind ({known}) nor a TOML file")
    full = {**{k: v for k, v in kept.items() if v is not None}, **table, **override}
    return ControllerSpec(spec, controller_from_table(full, source, base))


def _spec_table(path: str) -> dict:
    """The ``[controller]`` table of the TOML file `path`."""
    data = files.read_bytes(path, "toml", ScenarioError)
    try:
        doc = loads_toml(data.decode("utf-8"), f"controller spec {path}", ScenarioError)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"controller spec {path}: cannot be read as TOML: {exc}") from None
    table = doc.get("controller")
    if not isinstance(table, dict):
        raise ScenarioError(f"controller spec {path}: needs a [controller] table, got keys "
                            f"{', '.join(sorted(doc)) or 'none'}")
    return table


@dataclass
class Comparison:
    """A scenario run with several controllers over one drive."""

    scenario: Scenario
    drive: Drive
    specs: list[ControllerSpec]
    results: list[RunResult]

    def summaries(self) -> list[dict]:
        """``{"controller": label, **summary, "scenario_config": ...}`` per run (the keys of ``vrsim run
        --json``: `services.sim.as_run.with_settings`)."""
        return [{"controller": spec.label, **with_settings(result)}
                for spec, result in zip(self.specs, self.results, strict=True)]

    def to_dict(self) -> dict:
        """What ``vrsim compare --json`` prints."""
        return {"scenario": self.scenario.name, "runs": self.summaries()}


def compare(scenario: Scenario, specs: list[str] | None = None, look_ahead=None,
            progress=None) -> Comparison:
    """Run `scenario` once per controller spec over one shared drive.

    Parameters
    ----------
    scenario : Scenario
    specs : list of str, optional
        Controller specs (see the module docstring); default every built-in kind.
    look_ahead : float or "auto", optional
        ``look_ahead_s`` for every controller, overriding the scenario's and the specs'.
    progress : callable, optional
        ``progress(label, done_ticks, total_ticks)`` during each control loop.
    """
    labels = list(specs) if specs else _builtin_specs()
    resolved = [resolve_spec(s, scenario, look_ahead) for s in labels]   # all checked before driving
    shared = drive(scenario)
    results = []
    for spec in resolved:
        report = None if progress is None else (lambda done, total, label=spec.label:
                                                progress(label, done, total))
        results.append(control_and_account(shared, spec.config, report))
    return Comparison(scenario=scenario, drive=shared, specs=resolved, results=results)


def best_rows(summaries: list[dict], decimals: int | None = None) -> dict[str, set[int]]:
    """Per compared figure, the indices of the runs that are best in it: all that tie, at `decimals`
    decimal places if given (what a table shows); figures that are null for a run do not compete."""
    best = {}
    for m in COLUMNS:
        values = [s.get(m.key) for s in summaries]
        scored = [(_score(v if decimals is None else round(v, decimals), BETTER[m.key]), i)
                  for i, v in enumerate(values) if isinstance(v, (int, float)) and math.isfinite(v)]
        top = min((score for score, _ in scored), default=None)
        best[m.key] = {i for score, i in scored if score == top}
    return best


def _score(value: float, better: str) -> float:
    """Smaller is better."""
    return {"low": value, "high": -value, "zero": abs(value)}[better]
