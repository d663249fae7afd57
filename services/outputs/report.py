"""report.html: one self-contained page (the pictures are embedded): the machine check, the figures,
the error split into its causes, the settings the run used, the versions, the pictures and what each
figure means (from `services.sim.metrics.METRICS`). `vrsim run`, `vrsim report` and `vrsim evaluate`
write it with `page`."""

from __future__ import annotations

import base64
import html
import importlib.metadata
import os

from vrsim.common import __version__
from vrsim.maps.units import in_units
from vrsim.services.outputs.summary import fmt
from vrsim.services.outputs.track import TRACK_FILES
from vrsim.services.sim import metrics
from vrsim.services.sim.core import config_as_run
from vrsim.services.sim.error_split import error_split
from vrsim.services.sim.metrics import LOG_UNIT
from vrsim.services.sim.run import RunResult
from vrsim.services.sim.scenario_toml import to_toml, toml_value

# The scenario tables the report shows, in this order: the scenario as run (`services.sim.as_run`, every
# kind's default resolved), the plant as run (`config_as_run`).
SETTINGS = (("controller", "Controller"), ("implement", "Implement"), ("gnss", "GNSS"),
            ("speed_sensor", "Speed sensor"), ("tractor", "Tractor"), ("map", "Prescription"),
            ("timing", "Timing"), ("plant", "Metering drive (plant, as run)"))
STYLE = """body{font-family:sans-serif;margin:2em;max-width:1500px}
table{border-collapse:collapse;margin-bottom:1em}
td,th{padding:2px 10px;border-bottom:1px solid #ddd;text-align:left;vertical-align:top}
td.n{text-align:right}img{max-width:100%}.cols{display:flex;flex-wrap:wrap;gap:2em}"""
# The banner of a run the monitor does not hold whole; its style inline, so a whole run's page is as before.
BANNER_STYLE = "background:#fdd;border:2px solid #c00;padding:.5em 1em;font-weight:bold"


def versions() -> dict[str, str]:
    """vrsim's version and SUMO's (libsumo, which drives the tractor)."""
    try:
        sumo = importlib.metadata.version("libsumo")
    except importlib.metadata.PackageNotFoundError:
        sumo = "not installed"
    return {"vrsim": __version__, "SUMO (libsumo)": sumo}


def _esc(value) -> str:
    return html.escape(fmt(value) if not isinstance(value, (dict, list)) else str(value))


def figures_table(rows, values: dict) -> str:
    """One row per (label, key, unit) with the figure `values[key]`."""
    body = "".join(f"<tr><td>{html.escape(label)}</td><td class=n>{_esc(values[key])}</td>"
                   f"<td>{html.escape(unit)}</td></tr>" for label, key, unit in rows)
    return f"<table>{body}</table>"


def key_values(doc: dict) -> str:
    """A two-column table of a dict's keys and values."""
    body = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{_esc(v)}</td></tr>" for k, v in doc.items())
    return f"<table>{body}</table>"


def _settings_table(table: dict) -> str:
    """A two-column table of a scenario table's keys and values as a scenario file writes them
    (`services.sim.scenario_toml.toml_value`: every digit of a number), "unset" for None."""
    body = "".join(f"<tr><td>{html.escape(str(k))}</td><td><code>"
                   f"{html.escape('unset' if v is None else toml_value(v))}</code></td></tr>"
                   for k, v in table.items())
    return f"<table>{body}</table>"


def definitions(metrics, rate_unit: str = "") -> str:
    """What each figure means: its key, unit and description, from a table of `Metric` rows (figures
    in `LOG_UNIT` in `rate_unit`)."""
    body = "".join(f"<tr><td><code>{m.key}</code></td>"
                   f"<td>{html.escape(rate_unit if m.unit == LOG_UNIT else m.unit)}</td>"
                   f"<td>{html.escape(m.description)}</td></tr>" for m in metrics)
    return f"<table><tr><th>key</th><th>unit</th><th>meaning</th></tr>{body}</table>"


def _sections(sections) -> list[str]:
    return [f"<h2>{html.escape(heading)}</h2>\n{body}" for heading, body in sections]


def incomplete_note(summary: dict) -> str | None:
    """``incomplete: N of M ticks stored; reason R`` for a services run the monitor does not have whole
    (what `services.bus.monitor` records of its completeness), None for a complete one or a `vrsim run`
    (no such keys)."""
    if summary.get("complete", True):
        return None
    missing = sum(last - first + 1 for first, last in summary["missing_ticks"])
    reason = summary.get("end_reason", "unknown")
    stored, total = summary["ticks"], summary["ticks"] + missing
    after = " (no end announced: ticks after the last stored one not counted)" if reason == "unknown" else ""
    return f"incomplete: {stored:,} of {total:,} ticks stored; reason {reason}{after}"


def page(title: str, intro: str, sections, images, after, files_note: str, banner: str | None = None) -> str:
    """The page: `banner` (a warning shown first, e.g. `incomplete_note`), `sections`, then the PNGs at
    `images` (embedded), then `after`; sections are (heading, HTML) pairs."""
    parts = _sections(sections)
    for path in images:
        if os.path.isfile(path):
            with open(path, "rb") as fh:
                data = base64.b64encode(fh.read()).decode()
            name = html.escape(os.path.basename(path))
            parts.append(f'<figure><img alt="{name}" src="data:image/png;base64,{data}"></figure>')
    joined = "\n".join(parts + _sections(after))
    warning = f'<p class="incomplete" style="{BANNER_STYLE}">{html.escape(banner)}</p>\n' if banner else ""
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>{STYLE}</style>
</head><body>{warning}<h1>{html.escape(title)}</h1>
<p>{html.escape(intro)}</p>
{joined}
<p>{html.escape(files_note)}</p>
</body></html>
"""


def embedded_png(path: str) -> str:
    """A ``<figure>`` holding the PNG file `path` inline (the page stays one self-contained file)."""
    with open(path, "rb") as fh:
        data = base64.b64encode(fh.read()).decode()
    name = html.escape(os.path.basename(path))
    return f'<figure><img alt="{name}" src="data:image/png;base64,{data}"></figure>\n'


def _split_table(result: RunResult) -> str:
    """The error split into its causes (`services.sim.error_split`) as an HTML table and what it means."""
    grid, s = result.world.grid, result.summary

    def shown(mae_kg_ha):  # the error in the map's own unit, or its counterpart in the run's units
        return in_units(float(grid.in_map_unit(mae_kg_ha)), grid.map_unit, s.get("units", "metric"))

    rows = "\n".join(f"<tr><td>{html.escape(p.cause)}</td><td>{p.mass_balance_pct:+.2f}</td>"
                     f"<td>{shown(p.mae_kg_ha)[0]:+.2f}</td><td>{fmt(p.share_pct)}</td></tr>"
                     for p in error_split(result))
    return (f"<table><tr><th>cause</th><th>mass balance (pp)</th>"
            f"<th>mean absolute error ({html.escape(shown(0.0)[1])})</th><th>share of the error (%)</th></tr>"
            f"\n{rows}\n<tr><td>the run</td><td>{s['mass_balance_pct']:+.2f}</td>"
            f"<td>{shown(s['mae_kg_ha'])[0]:.2f}</td>"
            "<td>100</td></tr></table>\n<p>Geometry and section control: the same run with a meter whose "
            "shaft turns at exactly the speed the map asks for; machine limits: what clipping that speed "
            "to the shaft's range adds (the <code>ideal</code> controller); calibration: what the "
            "product's true meter constant and uneven flow add; metering: what the controller and plant "
            "add. See vrsim's docs/model.md, sections 7 and 9.</p>")


def write_html(result: RunResult, paths: dict[str, str]) -> None:
    """report.html of a run: machine check, figures, the error split, settings as run, versions and
    seed, pictures, definitions."""
    from vrsim.services.outputs.summary import shown, warnings

    summary = result.summary
    config = config_as_run(result.world.scenario)
    settings = "".join(f"<div><h3>{html.escape(label)}</h3>{_settings_table(config[key])}</div>"
                       for key, label in SETTINGS)
    scenario_file = html.escape(to_toml(result.world.scenario))
    run_info = {**versions(), "seed": summary["seed"], "scenario": result.world.scenario.source,
                "ticks": summary["ticks"]}
    # In the run's units, the rates in the map's unit (or its counterpart in those units).
    lines = result.machine_check.text(result.world.grid, summary.get("units", "metric")).splitlines()
    check = "<br>".join(html.escape(line.strip()) for line in lines)
    images = [paths[name] for name in ("map.png", "sections.png", "timeseries.png") if name in paths]
    sections = [("Machine check", f"<p>{check}</p>"),
                ("Figures", figures_table(*shown(summary))),
                ("Where the error comes from", _split_table(result)),
                ("Settings as run", f'<div class="cols">{settings}</div>\n<details><summary>The scenario '
                 f'as run, as a scenario file (<code>vrsim run</code> reruns it)</summary>'
                 f'<pre>{scenario_file}</pre></details>'),
                ("Versions and seed", key_values(run_info))]
    text = page(f"vrsim run: {summary['scenario']}", result.world.scenario.description, sections, images,
                [("What the figures mean", definitions(metrics.METRICS))],
                _files_note(result.world.grid.map_unit,
                            [TRACK_FILES[f] for f in result.world.scenario.output.track_formats]),
                banner=" ".join(filter(None, [incomplete_note(summary), *warnings(summary)])) or None)
    with open(paths["report.html"], "w") as fh:
        fh.write(text)


def _files_note(rate_unit: str, track_files) -> str:
    """What the files beside the report are: the rasters in the map's unit `rate_unit`, the track in
    `track_files` (file names; none: no per-tick track)."""
    track = "".join(f"{name}, " for name in track_files)
    return (f"Files beside this page: summary.json, {track}prescription.tif, as_applied.tif, error.tif "
            f"(GeoTIFF, {rate_unit}; nodata outside the field), passes.tif (GeoTIFF, passes per cell), "
            "taskdata/ (ISO 11783 TimeLog), as_applied_points.gpkg (or .zip).")
