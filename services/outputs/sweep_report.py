"""A sweep's report.html: one self-contained page (pictures embedded) with, for each accuracy metric,
its spread against each axis (mean and 95 % interval over seeds per configuration), the best
configurations per metric, the Pareto front of the two metrics named in ``[report] pareto``, and the
failed runs with their errors."""

from __future__ import annotations

import base64
import html
import io
import math

import numpy as np
from matplotlib.ticker import NullFormatter

from vrsim.common.written import written
from vrsim.services.outputs.plots import figure
from vrsim.services.outputs.summary import summary_rows
from vrsim.services.sim.metrics import RATE_UNIT, rate_key
from vrsim.services.sim.sweep import (
    METRIC_SENSE,
    Configuration,
    Sweep,
    best,
    configurations,
    mean_ci95,
    pareto_front,
)

UNITS = {key: unit for _, key, unit in summary_rows()}
LABELS = {key: label for label, key, _ in summary_rows()}
BEST_K = 3  # configurations listed per metric
MAX_TICKS = 12  # an axis with at most this many values is labelled at each value and joined by a line
SENSE_WORDS = {"min": "lower is better", "max": "higher is better", "zero": "closest to 0 is better"}


def _label(metric: str, rate_unit: str = RATE_UNIT) -> str:
    """``"Mean absolute error [lb/ac]"``: a rate figure in `rate_unit`, the runs' map unit."""
    if metric not in LABELS:
        return metric
    unit = rate_unit if UNITS[metric] == RATE_UNIT else UNITS[metric]
    return f"{LABELS[metric]} [{unit}]"


def _in_rate_unit(rows: list[dict]) -> tuple[list[dict], str]:
    """The rows with their rate figures in the map's own unit (each run's ``<key>_in_rate_unit``,
    `services.sim.sweep.tasks`) when every run's map has the same one; else as they are, in kg/ha."""
    units = {r.get("rate_unit") for r in rows if r.get("status") == "ok"}
    if len(units) != 1 or not isinstance(unit := units.pop(), str) or unit == RATE_UNIT:
        return rows, RATE_UNIT
    keys = [k for k in METRIC_SENSE if UNITS.get(k) == RATE_UNIT]
    return [{**r, **{k: r.get(f"{rate_key(k)}_in_rate_unit") for k in keys}} for r in rows], unit


def _png(fig) -> str:
    """A figure as an <img> with the PNG inline."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    data = base64.b64encode(buf.getvalue()).decode()
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


def _fmt(value: float, half: float = math.nan) -> str:
    if not math.isfinite(value):
        return "n/a"
    return f"{value:,.3g}" + (f" ± {half:,.2g}" if math.isfinite(half) else "")


def _positions(values: list) -> tuple[np.ndarray, list | None]:
    """x positions of axis values: the numbers themselves, or the index of a category (with its
    tick labels)."""
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return np.asarray(values, dtype=float), None
    cats = list(dict.fromkeys(str(v) for v in values))
    return np.array([cats.index(str(v)) for v in values], dtype=float), cats


def _plot_axis(configs: list[Configuration], axis_key: str, log: bool, rate_unit: str = RATE_UNIT):
    """One figure: every ranked metric against one axis, a point per configuration (mean over seeds,
    bar: 95 % interval) and a line through the mean per axis value, a colour per scenario."""
    metrics = list(METRIC_SENSE)
    ncols = 4
    nrows = math.ceil(len(metrics) / ncols)
    fig = figure(4.2 * ncols, 3.0 * nrows, left=0.05, right=0.98, bottom=0.05, top=0.93, hspace=0.55,
                 wspace=0.25)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    scenarios = list(dict.fromkeys(c.scenario for c in configs))
    shown = sorted({v for c in configs for v in _positions([dict(c.axes)[axis_key]])[0]})
    for ax, metric in zip(axes.flat, metrics, strict=False):
        if not any(len(c.values(metric)) for c in configs):
            ax.text(0.5, 0.5, "no value in any run\n(e.g. no rate step crossed)", ha="center",
                    va="center", transform=ax.transAxes, fontsize=8, color="0.4")
        cats = None
        for i, name in enumerate(scenarios):
            mine = [c for c in configs if c.scenario == name]
            x, cats = _positions([dict(c.axes)[axis_key] for c in mine])
            stats = np.array([mean_ci95(c.values(metric)) for c in mine]).reshape(-1, 2)
            color = f"C{i}"
            ax.errorbar(x, stats[:, 0], yerr=np.nan_to_num(stats[:, 1]), fmt="o", ms=3, alpha=0.6,
                        color=color, label=name)
            xs = np.unique(x)
            ys = [np.nanmean(stats[x == v, 0]) if np.isfinite(stats[x == v, 0]).any() else np.nan
                  for v in xs]
            if len(xs) <= MAX_TICKS:  # a line of means for discrete axes; a sampled axis shows points
                ax.plot(xs, ys, "-", color=color, lw=1)
        if log:
            ax.set_xscale("log")
        if cats:
            ax.set_xticks(range(len(cats)), cats)
        elif len(shown) <= MAX_TICKS:  # the swept values themselves, also on a log axis
            ax.set_xticks(shown, [f"{v:g}" for v in shown])
            ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(_label(metric, rate_unit), fontsize=9)
        ax.set_xlabel(axis_key, fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(metrics):]:
        ax.set_visible(False)
    if len(scenarios) > 1:
        axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"Each metric against {axis_key} (mean over seeds, bar: 95 % interval)")
    return fig


def _plot_pareto(configs: list[Configuration], pair: tuple[str, str], rate_unit: str = RATE_UNIT):
    """The two metrics of each configuration (means over seeds, bars: 95 % intervals), the Pareto
    front highlighted and numbered; returns the figure and the front's configurations in that
    numbering (along the first metric)."""
    mx, my = pair
    sx = np.array([mean_ci95(c.values(mx)) for c in configs]).reshape(-1, 2)
    sy = np.array([mean_ci95(c.values(my)) for c in configs]).reshape(-1, 2)
    front = pareto_front(sx[:, 0], sy[:, 0], mx, my)
    fig = figure(9, 6.5, left=0.09, right=0.97, bottom=0.09, top=0.96)
    ax = fig.subplots()
    ax.errorbar(sx[:, 0], sy[:, 0], xerr=np.nan_to_num(sx[:, 1]), yerr=np.nan_to_num(sy[:, 1]), fmt="o",
                ms=4, color="0.6", alpha=0.7, label="configurations")
    on_front = np.flatnonzero(front)[np.argsort(sx[front, 0])]
    ax.plot(sx[on_front, 0], sy[on_front, 0], "o-", color="C3", label="Pareto front")
    for number, i in enumerate(on_front, start=1):
        ax.annotate(str(number), (sx[i, 0], sy[i, 0]), fontsize=8, xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel(f"{_label(mx, rate_unit)} ({SENSE_WORDS[METRIC_SENSE[mx]]})")
    ax.set_ylabel(f"{_label(my, rate_unit)} ({SENSE_WORDS[METRIC_SENSE[my]]})")
    ax.legend()
    return fig, [configs[i] for i in on_front]


def _best_table(configs: list[Configuration], rate_unit: str = RATE_UNIT) -> str:
    rows = []
    for metric in METRIC_SENSE:
        for rank, (config, mean, half) in enumerate(best(configs, metric, BEST_K), start=1):
            name = f"{_label(metric, rate_unit)} ({SENSE_WORDS[METRIC_SENSE[metric]]})" if rank == 1 else ""
            rows.append(f"<tr><td>{html.escape(name)}</td><td>{rank}</td>"
                        f"<td>{html.escape(config.label())}</td><td>{_fmt(mean, half)}</td>"
                        f"<td>{len(config.values(metric))}</td></tr>")
    return ("<table><tr><th>metric</th><th>rank</th><th>configuration</th>"
            "<th>mean ± 95 %</th><th>seeds</th></tr>" + "\n".join(rows) + "</table>")


def _failed_table(rows: list[dict], axis_keys: list[str]) -> str:
    """The runs without a result: failed (the run's own error) or lost (dropped by the cluster)."""
    failed = [r for r in rows if r.get("status") != "ok"]
    if not failed:
        return "<p>No run failed or was lost.</p>"
    body = "\n".join(
        f"<tr><td>{html.escape(str(r['scenario']))}</td><td>{r['seed']}</td>"
        f"<td>{html.escape(', '.join(f'{k}={r.get(k)}' for k in axis_keys))}</td>"
        f"<td>{html.escape(str(r.get('status')))}</td>"
        f"<td>{html.escape(str(r.get('error')))}</td></tr>" for r in failed)
    return ("<table><tr><th>scenario</th><th>seed</th><th>axes</th><th>status</th><th>error</th></tr>"
            + body + "</table>")


def write_sweep_report(rows: list[dict], sweep: Sweep, path: str) -> None:
    """Write report.html for the result `rows` of `sweep` to `path`."""
    axis_keys = [a.key for a in sweep.axes]
    shown, unit = _in_rate_unit(rows)   # the rate figures in the runs' map unit
    configs = configurations(shown, axis_keys)
    n_ok = sum(r.get("status") == "ok" for r in rows)
    n_lost = sum(r.get("status") == "lost" for r in rows)
    lost = (f", {n_lost} lost to the cluster (<code>--resume</code> runs them again)" if n_lost else "")
    parts = [f"<p>{len(rows)} runs: {n_ok} ok, {len(rows) - n_ok - n_lost} failed{lost}; "
             f"{len(configs)} configurations; "
             f"design {html.escape(sweep.design)}"
             + (f" ({sweep.samples} samples)" if sweep.samples else "")
             + f"; seeds {html.escape(str(list(sweep.seeds)) if sweep.seeds else 'of each scenario')}; "
             f"scenarios {html.escape(', '.join(b.label for b in sweep.scenarios))}.</p>"]
    if configs:
        parts.append("<h2>Best configurations per metric</h2>" + _best_table(configs, unit))
        if sweep.pareto:
            fig, front = _plot_pareto(configs, sweep.pareto, unit)
            items = "".join(f"<li>{html.escape(c.label())}</li>" for c in front)
            parts.append(f"<h2>Pareto front: {html.escape(' vs '.join(sweep.pareto))}</h2>"
                         + _png(fig) + f"<ol>{items}</ol>")
        for axis in sweep.axes:
            parts.append(f"<h2>Against {html.escape(axis.key)}</h2>"
                         + _png(_plot_axis(configs, axis.key, axis.log, unit)))
    parts.append("<h2>Failed and lost runs</h2>" + _failed_table(rows, axis_keys))
    title = html.escape(f"vrsim sweep: {sweep.source}")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1500px}}table{{border-collapse:collapse}}
td,th{{padding:2px 10px;border-bottom:1px solid #ddd;text-align:left}}img{{max-width:100%}}</style>
</head><body><h1>{title}</h1>
{chr(10).join(parts)}
<p>Every run is a row of results.parquet and results.csv beside this page.</p>
</body></html>
"""
    with written(path) as temp, open(temp, "w", encoding="utf-8") as fh:
        fh.write(page)
