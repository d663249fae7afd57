"""report.html: one self-contained page (the pictures are embedded): the machine check, the summary
table, the error split into its causes and the pictures."""

from __future__ import annotations

import base64
import html
import os

from services.outputs.summary import SUMMARY_ROWS, fmt
from services.sim.error_split import error_split
from services.sim.run import RunResult


def split_table(result: RunResult) -> str:
    """The error split into its causes (`services.sim.error_split`) as an HTML table."""
    rows = "\n".join(f"<tr><td>{html.escape(p.cause)}</td><td>{p.mass_balance_pct:+.2f}</td>"
                     f"<td>{p.mae_kg_ha:+.2f}</td><td>{fmt(p.share_pct)}</td></tr>"
                     for p in error_split(result))
    s = result.summary
    return (f"<h2>Where the error comes from</h2>\n<table><tr><th>cause</th><th>mass balance (pp)</th>"
            f"<th>mean absolute error (kg/ha)</th><th>share of the error (%)</th></tr>\n{rows}\n"
            f"<tr><td>the run</td><td>{s['mass_balance_pct']:+.2f}</td><td>{s['mae_kg_ha']:.2f}</td>"
            "<td>100</td></tr></table>\n<p>Geometry and section control: the same run with a meter whose "
            "shaft turns at exactly the speed the map asks for; machine limits: what clipping that speed "
            "to the shaft's range adds (the <code>ideal</code> controller); metering: what the "
            "controller and plant add. See the README's accuracy section.</p>")


def write_html(result: RunResult, paths: dict[str, str]) -> None:
    rows = "\n".join(f"<tr><td>{html.escape(label)}</td><td>{fmt(result.summary[key])}</td>"
                     f"<td>{unit}</td></tr>" for label, key, unit in SUMMARY_ROWS)
    check = "<br>".join(html.escape(line.strip()) for line in result.machine_check.text().splitlines())
    images = ""
    for name in ("map.png", "sections.png", "timeseries.png"):
        if name in paths and os.path.isfile(paths[name]):
            with open(paths[name], "rb") as fh:
                data = base64.b64encode(fh.read()).decode()
            images += f'<figure><img alt="{name}" src="data:image/png;base64,{data}"></figure>\n'
    title = html.escape(f"vrsim run: {result.summary['scenario']}")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1500px}}table{{border-collapse:collapse}}
td{{padding:2px 10px;border-bottom:1px solid #ddd}}td:nth-child(2){{text-align:right}}
img{{max-width:100%}}</style>
</head><body><h1>{title}</h1>
<p>{html.escape(result.world.scenario.description)}</p>
<p>{check}</p>
<table>{rows}</table>
{split_table(result)}
{images}
<p>Files beside this page: summary.json, track.csv, as_applied.tif, error.tif (GeoTIFF, kg/ha),
passes.tif (GeoTIFF, passes per cell).</p>
</body></html>
"""
    with open(paths["report.html"], "w") as fh:
        fh.write(page)
