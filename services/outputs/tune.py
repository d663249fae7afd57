"""`vrsim tune`'s files and text: the best controller as a ``[controller]`` table a scenario can
include (``best_controller.toml``), the objective's history (``history.csv``) and the side-by-side
figures of the tuned and the scenario's own controller, their loops' margins and a warning when the
tuned loop's are too small (`services.sim.tune.TuneResult.margin_warning`)."""

from __future__ import annotations

import csv
import json
import math
import os

from vrsim.common.written import staged
from vrsim.controller.config import PID_KEYS
from vrsim.services.outputs.summary import shown
from vrsim.services.sim.metrics import METRICS, rate_key
from vrsim.services.sim.tune import TuneResult

COMPARED = tuple(m for m in METRICS if m.sense is not None and m.tolerance is not None)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):     # a user's class may take lists (a gain schedule's breakpoints)
        return "[" + ", ".join(map(_toml_value, value)) + "]"
    return json.dumps(str(value))   # a TOML basic string is a JSON string


def _controller_table(result: TuneResult) -> str:
    """The best controller as TOML text: a comment saying where it comes from and a [controller] table."""
    cfg = result.best
    keys = ["kind", *PID_KEYS, "params", "file", "class_name", "look_ahead_s", "look_ahead_tune"]
    lines = [f"# vrsim tune {result.scenario}: {result.objective} = {result.best_objective!r} after "
             f"{result.evaluations} evaluations", *(f"# {line}" for line in _margin_lines(result)),
             "[controller]"]
    for key in keys:
        value = getattr(cfg, key)
        if value is None or value == {} or (key == "look_ahead_tune" and value == 0):
            continue
        lines.append(f"{'class' if key == 'class_name' else key} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def write_tune(result: TuneResult, out_dir: str) -> dict[str, str]:
    """Write best_controller.toml and history.csv into `out_dir`; their paths."""
    names = {"best_controller": "best_controller.toml", "history": "history.csv"}
    with staged(out_dir, last=("best_controller.toml",)) as stage:  # both files or neither
        with open(os.path.join(stage, names["best_controller"]), "w", encoding="utf-8") as fh:
            fh.write(_controller_table(result))
        with open(os.path.join(stage, names["history"]), "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(result.history[0]) if result.history
                                    else ["evaluation"])
            writer.writeheader()
            writer.writerows(result.history)
    return {key: os.path.join(out_dir, name) for key, name in names.items()}


def _fmt(value) -> str:
    return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.4g}"


def _margin_lines(result: TuneResult) -> list[str]:
    """The tuned loop's margins in a line (or why there are none) and, if too small, the warning."""
    loop = result.tuned_loop
    if loop is None:
        return [f"loop margins: none ({result.no_loop_reason})"]
    lines = [f"loop margins of the tuned controller: gain {_fmt(loop.gain_margin)} "
             f"({_fmt(loop.gain_margin_db)} dB), phase {_fmt(loop.phase_margin_deg)} deg"]
    if result.margin_warning:
        lines.append(f"WARNING: the tuned loop's {result.margin_warning}")
    return lines


def _margin_rows(result: TuneResult, width: int, column: int) -> list[str]:
    """The two loops' gain and phase margins as rows of the table (`width` of the label, `column` of each
    value)."""
    rows = []
    for label, key in (("gain margin [dB]", "gain_margin_db"), ("phase margin [deg]", "phase_margin_deg")):
        tuned, own = (None if loop is None else getattr(loop, key)
                      for loop in (result.tuned_loop, result.baseline_loop))
        rows.append(f"  {label:<{width}} {_fmt(tuned):>{column}} {_fmt(own):>{column}}")
    return rows


def tune_text(result: TuneResult) -> str:
    """The best parameters and the figures of the tuned controller beside the scenario's own, their
    loops' margins, and a warning when the tuned loop's are too small."""
    values = ", ".join(f"{k} = {v:.6g}" for k, v in result.best_values.items())
    lines = [f"vrsim tune {result.scenario}: best {result.objective} ({result.sense}) = "
             f"{_fmt(result.best_objective)} with {result.best.kind} {values}",
             f"  {result.evaluations} evaluations in {result.generations} generations", "",
             f"  {'figure':<34} {'tuned':>12} {'scenario':>12}"]
    notes = [f"  {line}" for line in _margin_lines(result)]
    if "twin_mae_vs_target" in result.tuned:   # tuned on a log's drive (`vrsim tune --log`)
        lines[-1] = f"  {'figure':<52} {'tuned':>10} {'machine':>10}"
        return "\n".join(lines + _log_rows(result) + _margin_rows(result, 52, 10) + ["", *notes])
    # The rate figures in the map's own unit (`services.outputs.summary.shown`), named without _kg_ha then.
    rows, tuned = shown(result.tuned)
    baseline, units = shown(result.baseline)[1], {key: unit for _, key, unit in rows}
    for m in COMPARED:
        mark = " <" if m.key == result.objective else ""
        unit = units.get(m.key, m.unit)
        name = m.key if unit == m.unit else rate_key(m.key)
        lines.append(f"  {name + ' [' + unit + ']':<34} {_fmt(tuned.get(m.key)):>12} "
                     f"{_fmt(baseline.get(m.key)):>12}{mark}")
    return "\n".join(lines + _margin_rows(result, 34, 12) + ["", *notes])


# (label, replay figure) of a tune on a log's drive, in the log's rate unit.
LOG_ROWS = (("twin's error against its target", "twin_mae_vs_target"),
            ("twin's error against the log", "mae_vs_log"),
            ("machine's own logged error (target vs log)", "target_mae_vs_log"))


def _log_rows(result: TuneResult) -> list[str]:
    """The replay figures of the tuned controller beside the machine's own, in the log's unit."""
    unit = result.tuned.get("rate_unit") or "log's unit"
    out = []
    for label, key in LOG_ROWS:
        mark = " <" if key == result.objective else ""
        out.append(f"  {label + ' [' + unit + ']':<52} {_fmt(result.tuned.get(key)):>10} "
                   f"{_fmt(result.baseline.get(key)):>10}{mark}")
    return out
