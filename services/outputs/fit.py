"""The files and the text of `vrsim fit`: ``machine_fit.toml`` (the twin, for ``--machine``), ``fit.json``."""

from __future__ import annotations

import os

from vrsim.common.written import written
from vrsim.services.outputs.encode import dumps_text
from vrsim.services.sim.fit import FIT_PARAMS, MachineFit, fragment_text
from vrsim.services.sim.replay import EVENT_CLASSES

FIGURE_KEYS = ("compared_records", "mae_vs_log", "bias_vs_log", "rmse_vs_log", "r2_vs_log",
               "within_10pct_of_log_pct")


def fit_summary(fit: MachineFit, validated: dict | None = None) -> dict:
    """The fit as plain data: the parameters with their units and uncertainty, what could not be
    identified and why, the loop's time constants, and the figures (fitted, judged, validated)."""
    params = {p.name: {"value": fit.values[p.name], "std": fit.std.get(p.name), "unit": p.unit,
                       "identified": p.name not in fit.not_identified,
                       "why_not": fit.not_identified.get(p.name)} for p in FIT_PARAMS}
    return {"converged": fit.converged, "evaluations": fit.evaluations, "parameters": params,
            "rise_time_constant_s": fit.rise_time_constant_s,
            "fall_time_constant_s": fit.fall_time_constant_s, "fitted": fit.fitted, "judged": fit.judged,
            "default_machine": fit.default, "validated": validated}


def write_fit(fit: MachineFit, summary: dict, out_dir: str, source: str) -> dict[str, str]:
    """``machine_fit.toml`` and ``fit.json`` into `out_dir`, each whole or not at all."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {"machine": os.path.join(out_dir, "machine_fit.toml"), "fit": os.path.join(out_dir, "fit.json")}
    for key, text in (("machine", fragment_text(fit, source)), ("fit", dumps_text(summary, indent=True))):
        with written(paths[key]) as temp, open(temp, "w", encoding="utf-8") as fh:
            fh.write(text)
    return paths


def fit_text(fit: MachineFit, validated: dict | None, out_dir: str, unit: str) -> str:
    """What `vrsim fit` prints: each parameter with its uncertainty, then the twin against the log."""
    lines = ["Fitted machine" + ("" if fit.converged else " (did NOT converge: best found)")
             + f", {fit.evaluations} replays"]
    for p in FIT_PARAMS:
        value, sd = fit.values[p.name], fit.std.get(p.name)
        why = fit.not_identified.get(p.name)
        text = f"{value:.4g} {p.unit}" + (f" +- {sd:.2g}" if sd is not None else "")
        lines.append(f"  {p.name:24s} {text}" + (f"   not identifiable: {why}" if why else ""))
    lines.append(f"  {'loop time constant':24s} rise {fit.rise_time_constant_s:.2f} s, "
                 f"fall {fit.fall_time_constant_s:.2f} s (63 % of a step, dead time included)")
    for title, figures, default in (("on the records fitted", fit.fitted, fit.default["fitted"]),
                                    ("on the records held out", fit.judged, fit.default["judged"]),
                                    ("on the validation log", validated or {}, None)):
        if figures and figures.get("compared_records"):
            lines += [f"Twin vs log {title} ({figures['compared_records']} records), mean absolute "
                      f"error [{unit}]:"]
            lines += [_row(name, figures, default) for name in ("", *EVENT_CLASSES)]
    lines.append(f"  machine in {os.path.join(out_dir, 'machine_fit.toml')} (give it with --machine)")
    return "\n".join(lines)


def _row(event: str, figures: dict, default: dict | None) -> str:
    key = f"{event}_" if event else ""
    n = figures.get(f"{key}compared_records") or 0
    label = event or "all"
    if not n:
        return f"  {label:15s} no records"
    twin, target = figures[f"{key}mae_vs_log"], figures[f"{key}target_mae_vs_log"]
    text = f"  {label:15s} twin {twin:.4f}   target as prediction {target:.4f}"
    if default is not None and default.get(f"{key}mae_vs_log") is not None:
        text += f"   unfitted machine {default[f'{key}mae_vs_log']:.4f}"
    return text + f"   ({n} records)"
