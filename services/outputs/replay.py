"""What `vrsim replay` prints and writes: the figures as a short table (`text_replay`), and with
``--out DIR`` replay.parquet (one row per log timestamp), replay.png (logged, simulated and target
rate over time, a panel per session), replay_map.png (the logged rate and the twin minus the log on
the field) and summary.json (the figures, through the one JSON encoder), all whole or not at all
(`common.written.staged`, summary.json last).

Besides `services.sim.replay.Replay`'s figures, the summary may say what `vrsim replay` chose:
``log_sessions`` (the log's index of each session replayed, which the outputs number sessions by),
``target_from`` (``"log"`` or the prescription's path) and ``off_prescription_records``.
"""

from __future__ import annotations

import os

import numpy as np

from vrsim.common import MapError
from vrsim.common.written import staged
from vrsim.services.outputs.encode import dumps_text
from vrsim.services.outputs.plots import figure
from vrsim.services.sim.replay import EVENT_CLASSES, STANDSTILL_M_S, Replay, lonlat
from vrsim.services.sim.transitions import EVENTS, MIN_EVENTS

REPLAY_FILES = ("replay.parquet", "replay.png", "replay_map.png", "summary.json")
# (column, decimals): 0.001 s, 1e-8 degree (~1 mm), 1 mm/s, 1 mm, 1e-4 of the rate unit; None: as is
REPLAY_COLUMNS = (("time_s", 3), ("session", None), ("lon", 8), ("lat", 8), ("speed_m_s", 3),
                  ("sections_on", None), ("width_on_m", 3), ("target", 4), ("logged_applied", 4),
                  ("simulated_applied", 4), ("event", None), ("counts", None))
RATE_COLUMNS = ("target", "logged_applied", "simulated_applied")   # in the log's unit (schema metadata)
MAX_PANELS = 12            # replay.png shows at most this many sessions, the first ones
MAX_PLOT_POINTS = 20_000   # per panel: a longer session is drawn from every k-th record
# (label, summary key without its class prefix, unit: "rate" for the log's rate unit, decimals)
OVERALL_ROWS = (("Mean absolute error vs log", "mae_vs_log", "rate", 3),
                ("Bias vs log", "bias_vs_log", "rate", 3),
                ("RMSE vs log", "rmse_vs_log", "rate", 3),
                ("R^2 vs log", "r2_vs_log", "", 3),
                ("Within +-10 % of log", "within_10pct_of_log_pct", "%", 2))
CLASS_ROWS = OVERALL_ROWS[:2]
CLASS_LABELS = {"pass_start": "Pass starts", "rate_step": "Rate steps", "section_change": "Section changes",
                "steady": "Steady"}


def _log_sessions(rp: Replay) -> np.ndarray:
    """The log's session index of each replayed session: the summary's ``log_sessions`` (`vrsim replay`
    adds it: ``--session`` may pick some), else 0, 1, ..."""
    n = rp.records.sessions
    out = np.asarray(rp.summary.get("log_sessions", np.arange(n)), dtype=np.int64)
    if out.size != n:
        raise ValueError(f"log_sessions: {out.size} indices for {n} replayed sessions")
    return out


def _target_label(rp: Replay) -> str:
    """``"target (logged)"``, or ``"target (rx.tif)"`` for a prescription (the summary's ``target_from``)."""
    source = rp.summary.get("target_from", "log")
    return "target (logged)" if source == "log" else f"target ({os.path.basename(source)})"


# ------------------------------------------------------------------------------------------ text
def _number(value, decimals: int) -> str:
    """``"0.081"``; ``"n/a"`` for a figure that does not exist."""
    return "n/a" if value is None or not np.isfinite(value) else f"{value:,.{decimals}f}"


def _value(value, unit: str, decimals: int) -> str:
    """``"0.081 gal/ac"``; ``"n/a"`` for a figure that does not exist."""
    text = _number(value, decimals)
    return f"{text} {unit}" if unit and text != "n/a" else text


def _figure_lines(summary: dict, prefix: str, rows, unit: str) -> list[str]:
    """A line per figure: the twin's, its unit, then the target's as the prediction."""
    lines = []
    for label, key, kind, decimals in rows:
        shown = unit if kind == "rate" else kind
        twin = _number(summary[prefix + key], decimals)
        base = _value(summary[prefix + "target_" + key], shown, decimals)
        lines.append(f"    {label:<28} {twin:>10} {shown:<{len(unit)}}   (target as prediction {base})")
    return lines


def _count(n: int, noun: str) -> str:
    return f"{n:,} {noun}{'' if n == 1 else 's'}"


def _ranges(indices) -> str:
    """``"0-2, 5"`` of sorted indices 0, 1, 2, 5."""
    parts, start = [], None
    for k, i in enumerate(indices):
        start = i if start is None else start
        if k + 1 == len(indices) or indices[k + 1] != i + 1:
            parts.append(str(i) if i == start else f"{start}-{i}")
            start = None
    return ", ".join(parts)


def _off_map_text(summary: dict) -> str:
    off = summary.get("off_prescription_records")
    return f"; {_count(off, 'record')} off the prescription's rates (target 0 there)" if off else ""


def text_replay(rp: Replay) -> str:
    """The readable figures `vrsim replay` prints: the twin's against the log beside the logged target's
    (the prediction a twin must beat), over all the records that count and per event class."""
    s, unit = rp.summary, rp.summary["rate_unit"] or "(unit not stated)"
    lines = [f"vrsim replay: {rp.records.source}",
             f"  {s['records']:,} records in {_count(s['sessions'], 'session')} (the log's "
             f"{_ranges(_log_sessions(rp))}): {s['standstill_records']:,} standstill (below "
             f"{STANDSTILL_M_S:g} m/s), {s['closed_records']:,} with every section closed",
             f"  Rates in {unit}; {_target_label(rp)}" + _off_map_text(s),
             f"  All records ({s['compared_records']:,} compared)"]
    lines += _figure_lines(s, "", OVERALL_ROWS, unit)
    for name in EVENT_CLASSES:
        n = s[f"{name}_compared_records"]
        if not n:
            lines.append(f"  {CLASS_LABELS[name]}: no records")
            continue
        lines.append(f"  {CLASS_LABELS[name]} ({n:,} compared)")
        lines += _figure_lines(s, f"{name}_", CLASS_ROWS, unit)
    return "\n".join(lines + _event_lines(s))


def _event_lines(s: dict) -> list[str]:
    """The transitions by event class of the log and of the twin (`services.sim.replay.event_figures`)."""
    lines = [f"  Transitions by event (log | twin; n/a below {MIN_EVENTS} events)"]
    for kind in EVENTS:
        log, twin = (f"log_{kind}_", f"twin_{kind}_")
        events = f"{s[log + 'events']:>5,} | {s[twin + 'events']:<5,}"
        time_s = f"{_number(s[log + 'time_s_mean'], 2):>7} | {_number(s[twin + 'time_s_mean'], 2):<7}"
        peak = (f"{_number(s[log + 'peak_error_pct_mean'], 1):>6} | "
                f"{_number(s[twin + 'peak_error_pct_mean'], 1)}")
        lines.append(f"    {kind.replace('_', ' '):<12} events {events} time {time_s} s  peak error {peak} %")
    return lines


# ----------------------------------------------------------------------------------------- files
def write_replay(rp: Replay, out_dir: str) -> dict[str, str]:
    """Write replay.parquet, replay.png, replay_map.png and summary.json of `rp` into `out_dir`
    (created), whole or not at all; {file name: path}. Sessions are numbered as in the log
    (`_log_sessions`)."""
    with staged(out_dir, last=("summary.json",), error=MapError) as stage:
        paths = {name: os.path.join(stage, name) for name in REPLAY_FILES}
        _write_parquet(rp, paths["replay.parquet"])
        _plot_replay(rp, paths["replay.png"])
        _plot_replay_map(rp, paths["replay_map.png"])
        with open(paths["summary.json"], "w") as fh:
            fh.write(dumps_text(rp.summary, indent=True) + "\n")
    return {name: os.path.join(out_dir, name) for name in REPLAY_FILES}


def _replay_table(rp: Replay):
    """replay.parquet's table (`REPLAY_COLUMNS`): one row per log timestamp; the rates in the log's
    unit, which the schema's metadata ``rate_unit`` (and each rate column's ``unit``) says."""
    import pyarrow as pa

    rec = rp.records
    lon, lat = lonlat(rec)
    values = (rec.time_s, _log_sessions(rp)[rec.session].astype(np.int32), lon, lat,
              rec.speed_m_s, rec.sections_on.sum(axis=1, dtype=np.int16), rec.width_on_m, rec.target,
              rec.applied, rp.simulated, np.asarray(rp.event, dtype=object), np.asarray(rp.counts, bool))
    unit = rec.unit or ""
    fields, arrays = [], []
    for (name, decimals), v in zip(REPLAY_COLUMNS, values, strict=True):
        array = pa.array(v if decimals is None else np.round(np.asarray(v, float), decimals),
                         from_pandas=True)   # NaN becomes null: no rate there
        meta = {"unit": unit} if name in RATE_COLUMNS else None
        fields.append(pa.field(name, array.type, metadata=meta))
        arrays.append(array)
    schema = pa.schema(fields, metadata={"rate_unit": unit, "source": rec.source})
    return pa.Table.from_arrays(arrays, schema=schema)


def _write_parquet(rp: Replay, path: str) -> None:
    import pyarrow.parquet as pq

    pq.write_table(_replay_table(rp), path, compression="zstd",
                   use_dictionary=["session", "sections_on", "event", "counts"])


# ------------------------------------------------------------------------------------- replay.png
def _plot_replay(rp: Replay, path: str) -> None:
    """Logged, simulated and target rate over each session's time, a panel per session (the first
    `MAX_PANELS`), stacked; the twin's and the target's mean absolute error in each panel's title."""
    rec, unit = rp.records, rp.records.unit or "unit not stated"
    sessions = _log_sessions(rp)
    shown = min(rec.sessions, MAX_PANELS)
    fig = figure(11, 1.2 + 1.8 * max(shown, 1), layout="constrained")
    axes = np.atleast_1d(fig.subplots(max(shown, 1), 1, squeeze=False)[:, 0])
    for k, ax in enumerate(axes[:shown]):
        _panel(ax, rp, k, sessions[k], unit)
    axes[0].legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("time since the session's start (s)")
    fig.supylabel(f"rate ({unit})")
    name = os.path.basename(os.path.normpath(rec.source))
    more = (f"; sessions shown: {shown} of {rec.sessions} (--session picks others)"
            if rec.sessions > shown else "")
    fig.suptitle(f"{name}: logged, simulated and target rate{more}")
    fig.savefig(path, dpi=90)


def _panel(ax, rp: Replay, k: int, log_session: int, unit: str) -> None:
    rec = rp.records
    rows = np.flatnonzero(rec.session == k)
    step = max(1, rows.size // MAX_PLOT_POINTS)
    part = rows[::step]
    t = rec.time_s[part] - rec.time_s[rows[0]]
    ax.plot(t, rec.target[part], label=_target_label(rp), color="0.35", lw=1.0, ls="--")
    ax.plot(t, rec.applied[part], label="logged applied", color="C0", lw=1.0)
    ax.plot(t, rp.simulated[part], label="simulated applied", color="C1", lw=1.0)
    keep = rows[rp.counts[rows] & np.isfinite(rp.simulated[rows])]
    twin = _mae(rp.simulated[keep], rec.applied[keep])
    base = _mae(rec.target[keep], rec.applied[keep])
    start_s, span_s = rec.time_s[rows[0]], rec.time_s[rows[-1]] - rec.time_s[rows[0]]
    ax.set_title(f"session {log_session}: {rows.size:,} records, {span_s:,.0f} s from {start_s:,.0f} s of "
                 f"the log; MAE vs log: twin {_value(twin, unit, 3)}, "
                 f"target {_value(base, unit, 3)}", fontsize="small", loc="left")
    ax.margins(x=0.01)


def _mae(pred: np.ndarray, log: np.ndarray) -> float | None:
    err = pred - log
    err = err[np.isfinite(err)]
    return float(np.mean(np.abs(err))) if err.size else None


# --------------------------------------------------------------------------------- replay_map.png
def _plot_replay_map(rp: Replay, path: str) -> None:
    """The records on the field: the logged rate, and the twin minus the log (a diverging scale
    symmetric about 0, at least 1 % of the median target either way), in metres of the log's UTM zone
    from its south-west corner; records that do not count are left out."""
    rec, unit = rp.records, rp.records.unit or "unit not stated"
    keep = rp.counts & np.isfinite(rp.simulated)
    step = max(1, int(keep.sum()) // (4 * MAX_PLOT_POINTS))
    rows = np.flatnonzero(keep)[::step]
    x, y = rec.x_m[rows] - rec.x_m[rows].min(), rec.y_m[rows] - rec.y_m[rows].min()
    err = rp.simulated[rows] - rec.applied[rows]
    floor = 0.01 * float(np.nanmedian(np.abs(rec.target[rows]))) if rows.size else 1.0
    emax = max(float(np.nanpercentile(np.abs(err), 99)) if rows.size else 0.0, floor, 1e-9)
    # The logged rate's colours span its 1st to 99th percentile: a start-up's peak would flatten the rest.
    low, high = np.nanpercentile(rec.applied[rows], [1, 99]) if rows.size else (0.0, 1.0)
    aspect = float(np.ptp(y) / max(np.ptp(x), 1.0)) if rows.size else 1.0
    fig = figure(12, float(np.clip(3.0 * aspect, 4.0, 9.0)), layout="constrained")
    for ax, values, title, cmap, lim in (
            (fig.add_subplot(1, 2, 1), rec.applied[rows], f"logged applied ({unit})", "viridis", (low, high)),
            (fig.add_subplot(1, 2, 2), err, f"twin minus log ({unit})", "RdBu_r", (-emax, emax))):
        kw = {"vmin": lim[0], "vmax": lim[1]}
        points = ax.scatter(x, y, c=values, s=2, cmap=cmap, linewidths=0, **kw)
        fig.colorbar(points, ax=ax, shrink=0.8)
        ax.set_title(title, fontsize="small")
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
    fig.suptitle(f"{os.path.basename(os.path.normpath(rec.source))}: {rows.size:,} records on the map")
    fig.savefig(path, dpi=90)
