"""What `vrsim evaluate --out DIR` writes: evaluation.json, error.tif (applied minus target per cell,
in the log's unit), error_map.png, timeseries.png (a panel per session of the log, at most
`MAX_PANELS`) and report.html (the page `vrsim run` writes, with the log's figures)."""

from __future__ import annotations

import os

import numpy as np

from vrsim.common.written import staged
from vrsim.maps import Grid, write_map
from vrsim.maps.log_records import SESSION_GAP_S
from vrsim.services.outputs.encode import dumps_text
from vrsim.services.outputs.plots import figure
from vrsim.services.outputs.report import definitions, figures_table, key_values, page, versions
from vrsim.services.outputs.summary import fmt
from vrsim.services.sim.evaluate import Evaluation
from vrsim.services.sim.metrics import AREA_OR_RECORDS, AREA_OR_TIMESTAMPS, LOG_UNIT, POINT_METRICS

MAX_PLOT_POINTS = 20_000
MAX_PANELS = 12  # sessions drawn in timeseries.png: more would be too small to read


def _rows(ev: Evaluation):
    """The report's rows (label, key, unit) of `POINT_METRICS` with a label: rate figures in the log's
    unit, weighted shares in what they are shares of, a count with the setting it was found with."""
    weighting = ev.metrics.weighting
    units = {LOG_UNIT: ev.unit, AREA_OR_RECORDS: "% of area" if weighting == "area" else "% of records",
             AREA_OR_TIMESTAMPS: "% of area" if weighting == "area" else "% of timestamps"}
    notes = _notes(ev.metrics)
    return tuple((m.label, m.key, notes.get(m.key, units.get(m.unit, m.unit))) for m in POINT_METRICS
                 if m.label)


def _notes(m) -> dict[str, str]:
    """What the counts and the weighting were found with: the settings of the rows without a label."""
    kept = "kept in the figures (--include-outliers)" if m.outliers_included else "left out"
    return {"weighting": ("(each record's distance x width)" if m.weighting == "area"
                          else "(each record alike: not every record's distance and width logged)"),
            "standstill_records": f"(ground speed below {m.standstill_speed_m_s:g} m/s, from {m.speed_from})",
            "outlier_records": f"(applied above {m.outlier_multiple:g}x the target; {kept})",
            "sessions": f"(records more than {SESSION_GAP_S:g} s apart begin a new one)"}


def text_evaluation(ev: Evaluation) -> str:
    """The readable figures `vrsim evaluate` prints."""
    summary = ev.summary()
    lines = [f"vrsim evaluate: {ev.log.source} ({ev.log.points:,} records, {ev.log.format}) against "
             f"{ev.against}" + (f", delay {ev.delay_s:g} s" if ev.delay_s else "")]
    left = sum(ev.excluded.values())
    for label, key, unit in _rows(ev):
        if key == "standstill_records":  # the records left out, each reason after the other
            lines.append(f"  {'Records left out':<38} {left:>14,} {_excluded_text(ev.excluded)}")
        lines.append(f"  {label:<38} {fmt(summary[key]):>14} {unit}")
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
                [("Figures", figures_table(_rows(ev), ev.summary())), ("The log", key_values(info))],
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


def _session_panels(ev: Evaluation) -> list[int]:
    """The sessions timeseries.png shows, in time order: those with a record compared, at most
    `MAX_PANELS` (the ones with the most records compared)."""
    counts = np.bincount(ev.session[ev.compared], minlength=int(ev.session.max()) + 1)
    busiest = np.argsort(-counts, kind="stable")[:MAX_PANELS]
    return sorted(int(s) for s in busiest if counts[s] > 0)


def _plot_log_timeseries(ev: Evaluation, path: str) -> int:
    """Applied and target rate over time, a panel per session (`_session_panels`): a log of several
    days on one time axis would be a few vertical lines. Returns the number of panels."""
    shown = _session_panels(ev)
    cols = 1 if len(shown) <= 4 else 2 if len(shown) <= 8 else 3
    rows = -(-len(shown) // cols)
    fig = figure(11, 1.0 + 2.6 * rows, layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False, sharey=True).ravel()
    step = max(1, int(np.isin(ev.session, shown).sum()) // MAX_PLOT_POINTS)
    for i, (ax, session) in enumerate(zip(axes, shown, strict=False)):
        _plot_session(ev, ax, session, step)
        if i % cols:  # the panels of a row share the first one's rate axis
            ax.set_ylabel("")
    for ax in axes[len(shown):]:
        ax.set_visible(False)
    axes[0].legend(loc="upper right")
    total = ev.metrics.sessions
    if len(shown) < total:
        said = f"{len(shown)} of {total} sessions shown (those with the most points compared)"
    else:
        said = f"{total} session{'s' if total > 1 else ''}"
    fig.suptitle(f"{os.path.basename(os.path.normpath(ev.log.source))}: applied and target rate; {said}")
    fig.savefig(path, dpi=90)
    return len(shown)


def _plot_session(ev: Evaluation, ax, session: int, step: int) -> None:
    """One session's panel: time since its first record, in s, or in min past 10 minutes."""
    idx = np.flatnonzero(ev.session == session)[::step]
    t = ev.log.time_s[idx]
    timed = np.isfinite(t).any()
    t0 = float(np.nanmin(t)) if timed else 0.0
    span_s = float(np.nanmax(t)) - t0 if timed else 0.0
    scale, unit = (60.0, "min") if span_s > 600 else (1.0, "s")
    applied = np.where(ev.compared[idx], ev.log.applied[idx], np.nan)
    ax.plot((t - t0) / scale, ev.target[idx], label=f"target ({ev.against})", lw=1.2)
    ax.plot((t - t0) / scale, applied, label="applied (points compared)", lw=1.0)
    ax.set_xlabel(f"time since the session's first record ({unit})")
    ax.set_ylabel(f"rate ({ev.unit})")
    start = ""
    if ev.log.start is not None:
        when = (ev.log.start + np.timedelta64(round(t0 * 1000), "ms")).astype("datetime64[s]")
        start = f", from {str(when).replace('T', ' ')}"
    ax.set_title(f"session {session + 1}{start}, {span_s / 60:.1f} min", fontsize=9)
