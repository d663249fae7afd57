"""What `vrsim compare` prints and writes: the side-by-side table (text and HTML), overlaid time series
at the same rate steps, the error maps, all on one self-contained page (compare.html)."""

from __future__ import annotations

import html
import math
import os

import numpy as np

from vrsim.common.written import staged
from vrsim.services.outputs.plots import figure
from vrsim.services.outputs.report import embedded_png
from vrsim.services.sim.compare import BETTER, COLUMNS, Comparison, best_rows
from vrsim.services.sim.metrics import RATE_UNIT, rate_key
from vrsim.services.sim.transitions import rate_steps

BEST = "*"
DECIMALS = 3    # figures shown, and compared for "best", to three decimals
STEP_PANELS = 4             # rate steps shown in compare_timeseries.png
STEP_WINDOW_S = (-2.0, 5.0)  # shown around each, s


def _cell(value) -> str:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:,.{DECIMALS}f}"
    return "n/a" if value is None else str(value)


def _shown(summary: dict, metric) -> tuple[object, str]:
    """A column's figure of one run and its unit: a rate in the map's own unit (the summary's
    ``in_rate_unit``), any other figure as it is."""
    if metric.unit == RATE_UNIT and rate_key(metric.key) in summary.get("in_rate_unit", {}):
        return summary["in_rate_unit"][rate_key(metric.key)], summary["rate_unit"]
    return summary[metric.key], metric.unit


def table_text(comparison: Comparison) -> str:
    """The table ``vrsim compare`` prints: one row per controller, one column per figure, the best of
    each column marked with ``*``."""
    summaries = comparison.summaries()
    best = best_rows(summaries, DECIMALS)
    label_w = max(12, *(len(s["controller"]) for s in summaries)) + 2
    widths = [11] * len(COLUMNS)
    head1 = " " * label_w + "".join(f"{_short(m.key):>{w}}" for m, w in zip(COLUMNS, widths, strict=True))
    units = [_shown(summaries[0], m)[1] for m in COLUMNS]   # one map: one unit for every run
    head2 = f"{'controller':<{label_w}}" + "".join(f"{'[' + u + ']' if u else '':>{w}}"
                                                  for u, w in zip(units, widths, strict=True))
    lines = [f"vrsim compare: {comparison.scenario.name} ({summaries[0]['ticks']:,} ticks, one drive "
             f"shared by {len(summaries)} controllers)", head1, head2]
    for i, s in enumerate(summaries):
        cells = "".join(f"{_cell(_shown(s, m)[0]) + (BEST if i in best[m.key] else ' '):>{w}}"
                        for m, w in zip(COLUMNS, widths, strict=True))
        lines.append(f"{s['controller']:<{label_w}}{cells}")
    lines.append(f"{BEST} best in its column ({_directions()})")
    return "\n".join(lines)


# Column headers of the text table (the HTML table uses the metrics' labels).
HEADERS = {
    "mass_balance_pct": "mass bal", "mae_kg_ha": "MAE", "rmse_kg_ha": "RMSE", "bias_kg_ha": "bias",
    "within_5pct_area_pct": "in 5%", "within_10pct_area_pct": "in 10%", "transition_time_s_mean": "trans t",
    "transition_time_s_p95": "trans t95", "transition_distance_m_mean": "trans d",
    "transition_distance_m_p95": "trans d95", "off_target_kg": "off-target", "coverage_pct": "coverage",
    "overlap_area_pct": "overlap", "skip_area_pct": "skipped", "overlap_kg": "overlap kg",
    "limited_time_pct": "lim time", "limited_area_pct": "lim area",
}


def _short(key: str) -> str:
    return HEADERS[key]


def _directions() -> str:
    groups = {"low": "lowest", "high": "highest", "zero": "closest to 0"}
    return "; ".join(f"{word}: {', '.join(_short(k) for k, b in BETTER.items() if b == kind)}"
                     for kind, word in groups.items())


def write_page(comparison: Comparison, out_dir: str) -> str:
    """Write ``compare.html`` (table, time series, error maps; pictures embedded) into `out_dir`."""
    with staged(out_dir, last=("compare.html",)) as stage:  # the page and its pictures, whole or not at all
        _write_page(comparison, stage)
    return os.path.join(out_dir, "compare.html")


def _write_page(comparison: Comparison, out_dir: str) -> None:
    pictures = [os.path.join(out_dir, "compare_timeseries.png"), os.path.join(out_dir, "compare_errors.png")]
    _plot_timeseries(comparison, pictures[0])
    _plot_errors(comparison, pictures[1])
    path = os.path.join(out_dir, "compare.html")
    title = html.escape(f"vrsim compare: {comparison.scenario.name}")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1600px}}table{{border-collapse:collapse}}
td,th{{padding:2px 8px;border-bottom:1px solid #ddd;text-align:right}}td:first-child{{text-align:left}}
td.best{{font-weight:bold;background:#e6f4e6}}img{{max-width:100%}}</style>
</head><body><h1>{title}</h1>
<p>{html.escape(comparison.scenario.description)}</p>
<p>One drive (seed {comparison.scenario.seed}: the same SUMO track and sensor noise) for every controller.
Best of each column in bold ({html.escape(_directions())}).</p>
{_table_html(comparison)}
{"".join(embedded_png(p) for p in pictures)}
</body></html>
"""
    with open(path, "w") as fh:
        fh.write(page)


def _table_html(comparison: Comparison) -> str:
    """The table as HTML: controllers in rows, figures in columns, the best of each column marked."""
    summaries = comparison.summaries()
    best = best_rows(summaries, DECIMALS)
    head = "".join(f"<th>{html.escape(m.label or m.key)}<br>{html.escape(_shown(summaries[0], m)[1])}</th>"
                   for m in COLUMNS)
    rows = []
    for i, s in enumerate(summaries):
        cells = "".join(f'<td{" class=best" if i in best[m.key] else ""}>{_cell(_shown(s, m)[0])}</td>'
                        for m in COLUMNS)
        rows.append(f"<tr><td>{html.escape(s['controller'])}</td>{cells}</tr>")
    return f"<table><tr><th>controller</th>{head}</tr>\n" + "\n".join(rows) + "\n</table>"


def _step_windows(result, count: int = STEP_PANELS) -> list[int]:
    """Ticks of up to `count` rate steps (on the true landing path) whose window around them holds no
    other step, spread over the run: the steps every controller's time series are shown at."""
    t = result.track["time_s"]
    steps = rate_steps(result.landing.prescribed_kg_ha, np.asarray(result.track["implement_on"], bool))
    if not len(steps):   # a uniform map, or one whose steps all fall outside working
        return []
    before, after = STEP_WINDOW_S
    gaps = np.diff(t[steps])
    alone = np.r_[True, gaps > after] & np.r_[gaps > after, True]   # no other step within `after` s
    clean = [int(k) for k, ok in zip(steps, alone, strict=True) if ok and t[k] + before >= t[0]]
    if len(clean) <= count:
        return clean
    return [clean[i] for i in np.linspace(0, len(clean) - 1, count).round().astype(int)]


def _plot_timeseries(comparison: Comparison, path: str) -> None:
    """Shaft speed and applied rate of every controller around the same rate steps (the drive is
    shared, so the steps are the same for all), time from each step; target and prescription in black."""
    first = comparison.results[0]
    grid = first.world.grid  # rates in the map's own unit
    steps = _step_windows(first)
    t = first.track["time_s"]
    cols = max(1, len(steps))
    fig = figure(4.2 * cols + 1.5, 7, layout="constrained")
    axes = fig.subplots(2, cols, squeeze=False)
    before, after = STEP_WINDOW_S
    for col, k in enumerate(steps):
        w = slice(int(np.searchsorted(t, t[k] + before)), int(np.searchsorted(t, t[k] + after)))
        rel = t[w] - t[k]
        ax1, ax2 = axes[0, col], axes[1, col]
        ax1.plot(rel, first.control["target_shaft_rpm"][w], color="k", lw=1.4,
                 label=f"target of {comparison.specs[0].label}")
        ax2.plot(rel, grid.in_map_unit(first.landing.prescribed_kg_ha[w]), color="k", lw=1.4,
                 label="prescribed where it lands")
        for spec, result in zip(comparison.specs, comparison.results, strict=True):
            ax1.plot(rel, result.control["shaft_rpm"][w], lw=0.9, label=spec.label)
            ax2.plot(rel, grid.in_map_unit(result.landing.applied_kg_ha[w]), lw=0.9, label=spec.label)
        ax1.set_title(f"rate step at {t[k]:.0f} s")
        ax2.set_xlabel("time from the step (s)")
        for ax in (ax1, ax2):
            ax.axvline(0.0, color="grey", lw=0.6, ls="--")
            ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("metering shaft (rpm)")
    axes[1, 0].set_ylabel(f"rate ({grid.map_unit})")
    axes[1, -1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    axes[0, -1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    fig.suptitle(f"{comparison.scenario.name}: every controller on the same drive, at the same rate steps"
                 + ("" if steps else " (no rate step crossed)"))
    fig.savefig(path, dpi=90)


def _plot_errors(comparison: Comparison, path: str) -> None:
    """Applied minus prescribed (in the map's unit) inside the field, one map per controller, one colour
    scale."""
    grid = comparison.results[0].world.grid
    west, south, east, north = grid.bounds
    extent = (0.0, east - west, 0.0, north - south)
    shown = np.where(comparison.results[0].in_field, 1.0, np.nan)
    errors = [grid.in_map_unit(r.as_applied.applied_kg_ha - grid.rates_kg_ha) * shown
              for r in comparison.results]
    finite = np.concatenate([np.abs(e[np.isfinite(e)]) for e in errors])
    emax = max(float(np.percentile(finite, 98)) if finite.size else 1.0, float(grid.in_map_unit(1.0)))
    cols = min(3, len(errors))
    rows = math.ceil(len(errors) / cols)
    fig = figure(5.5 * cols, 4.8 * rows, layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    fx, fy = comparison.results[0].world.field.polygon.exterior.xy
    for ax, spec, err, result in zip(axes.flat, comparison.specs, errors, comparison.results, strict=False):
        im = ax.imshow(err, extent=extent, origin="upper", cmap="RdBu_r", vmin=-emax, vmax=emax,
                       interpolation="nearest")
        ax.plot(np.asarray(fx) - west, np.asarray(fy) - south, color="k", lw=0.8)
        ax.set_title(f"{spec.label}: MAE {_cell(result.summary['in_rate_unit']['mae'])} {grid.map_unit}")
        ax.set_aspect("equal")
    for ax in list(axes.flat)[len(errors):]:
        ax.axis("off")
    fig.colorbar(im, ax=axes, label=f"applied - prescribed ({grid.map_unit})", shrink=0.8)
    fig.suptitle(f"{comparison.scenario.name}: error maps (same colour scale)")
    fig.savefig(path, dpi=80)
