"""What `vrsim evaluate --out DIR` writes: evaluation.json, error.tif (applied minus target per cell,
in the log's unit), error_map.png, timeseries.png and report.html (the page `vrsim run` writes, with
the log's figures)."""

from __future__ import annotations

import os

import numpy as np

from common.written import staged
from maps import Grid, write_map
from services.outputs.encode import dumps_text
from services.outputs.plots import figure
from services.outputs.report import definitions, figures_table, key_values, page, versions
from services.outputs.summary import fmt
from services.sim.evaluate import Evaluation
from services.sim.metrics import LOG_UNIT, POINT_METRICS

MAX_PLOT_POINTS = 20_000


def _rows(unit: str):
    """The report's rows (label, key, unit) of `POINT_METRICS`, rate figures in `unit`."""
    return tuple((m.label, m.key, unit if m.unit == LOG_UNIT else m.unit) for m in POINT_METRICS)


def text_evaluation(ev: Evaluation) -> str:
    """The readable figures `vrsim evaluate` prints."""
    summary = ev.summary()
    lines = [f"vrsim evaluate: {ev.log.source} ({ev.log.points:,} records, {ev.log.format}) against "
             f"{ev.against}" + (f", delay {ev.delay_s:g} s" if ev.delay_s else "")]
    lines += [f"  {label:<38} {fmt(summary[key]):>14} {unit}" for label, key, unit in _rows(ev.unit)]
    left = sum(ev.excluded.values())
    lines.append(f"  {'Records left out':<38} {left:>14,} {_excluded_text(ev.excluded)}")
    return "\n".join(lines)


def _excluded_text(excluded: dict) -> str:
    """``"(68 implement off, 1,158 no section on)"``: the reasons records were left out, or ``""``."""
    parts = [f"{n:,} {reason.replace('_', ' ')}" for reason, n in excluded.items() if n]
    return f"({', '.join(parts)})" if parts else ""


def write_evaluation(ev: Evaluation, errors: Grid, out_dir: str) -> dict[str, str]:
    """Write every file of an evaluation into `out_dir` (created), whole or not at all; {name: path}."""
    names = ("evaluation.json", "error.tif", "error_map.png", "timeseries.png", "report.html")
    with staged(out_dir, last=("evaluation.json",)) as stage:
        _write_evaluation(ev, errors, {name: os.path.join(stage, name) for name in names})
    return {name: os.path.join(out_dir, name) for name in names}


def _write_evaluation(ev: Evaluation, errors: Grid, paths: dict[str, str]) -> None:
    with open(paths["evaluation.json"], "w") as fh:
        fh.write(dumps_text(ev.summary(), indent=True) + "\n")
    write_map(errors, paths["error.tif"])
    _plot_error_map(ev, errors, paths["error_map.png"])
    _plot_log_timeseries(ev, paths["timeseries.png"])
    info = {"log": ev.log.source, "format": ev.log.format, "records": ev.log.points,
            "start": str(ev.log.start) if ev.log.start is not None else "not logged",
            "compared with": ev.against, "delay_s": ev.delay_s,
            "records left out": f"{sum(ev.excluded.values()):,} {_excluded_text(ev.excluded)}", **versions()}
    text = page(f"vrsim evaluate: {os.path.basename(os.path.normpath(ev.log.source))}",
                "An as-applied log against its targets.",
                [("Figures", figures_table(_rows(ev.unit), ev.summary())), ("The log", key_values(info))],
                [paths["error_map.png"], paths["timeseries.png"]],
                [("What the figures mean", definitions(POINT_METRICS, ev.unit))],
                "Files beside this page: evaluation.json, error.tif (GeoTIFF, applied minus target per cell, "
                f"{ev.unit}; nodata where no point was compared).")
    with open(paths["report.html"], "w") as fh:
        fh.write(text)


def _plot_error_map(ev: Evaluation, errors: Grid, path: str) -> None:
    west, south, east, north = errors.bounds
    data = errors.rates_kg_ha
    emax = float(np.nanpercentile(np.abs(data), 98)) if np.isfinite(data).any() else 1.0
    emax = emax if emax > 0 else 1.0
    aspect = (east - west) / (north - south)  # the figure follows the map's shape, within bounds
    fig = figure(float(np.clip(7.0 * aspect + 3.0, 5.0, 15.0)), 8, left=0.12, right=0.95, bottom=0.08,
                 top=0.92)
    ax = fig.subplots()
    im = ax.imshow(data, extent=(0.0, east - west, 0.0, north - south), origin="upper", cmap="RdBu_r",
                   vmin=-emax, vmax=emax, interpolation="nearest")
    step = max(1, ev.log.points // MAX_PLOT_POINTS)
    ax.plot(ev.x_m[::step] - west, ev.y_m[::step] - south, color="0.5", lw=0.3)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m) of the map's south-west corner")
    fig.colorbar(im, ax=ax, label=f"applied - target ({ev.unit})", shrink=0.8)
    ax.set_title(f"applied minus {ev.against}: MAE {fmt(ev.metrics.mae)} {ev.unit}")
    fig.savefig(path, dpi=90)


def _plot_log_timeseries(ev: Evaluation, path: str) -> None:
    log = ev.log
    step = max(1, log.points // MAX_PLOT_POINTS)
    t = log.time_s[::step]
    fig = figure(11, 5, left=0.08, right=0.97, bottom=0.11, top=0.9)
    ax = fig.subplots()
    ax.plot(t, ev.target[::step], label=f"target ({ev.against})", lw=1.2)
    ax.plot(t, np.where(ev.compared, log.applied, np.nan)[::step], label="applied (points compared)", lw=1.0)
    ax.set_xlabel("time since the first record (s)")
    ax.set_ylabel(f"rate ({ev.unit})")
    ax.legend(loc="upper right")
    ax.set_title(f"{os.path.basename(os.path.normpath(log.source))}: applied and target rate")
    fig.savefig(path, dpi=90)
