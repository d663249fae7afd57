"""report.html: one self-contained page (the pictures are embedded) with the summary table."""

from __future__ import annotations

import base64
import html
import os

from services.outputs.summary import SUMMARY_ROWS, fmt
from services.sim.run import RunResult


def embedded_png(path: str) -> str:
    """A ``<figure>`` holding the PNG file `path` inline (the page stays one self-contained file)."""
    with open(path, "rb") as fh:
        data = base64.b64encode(fh.read()).decode()
    name = html.escape(os.path.basename(path))
    return f'<figure><img alt="{name}" src="data:image/png;base64,{data}"></figure>\n'


def write_html(result: RunResult, paths: dict[str, str]) -> None:
    rows = "\n".join(f"<tr><td>{html.escape(label)}</td><td>{fmt(result.summary[key])}</td>"
                     f"<td>{unit}</td></tr>" for label, key, unit in SUMMARY_ROWS)
    images = "".join(embedded_png(paths[name]) for name in ("map.png", "timeseries.png")
                     if name in paths and os.path.isfile(paths[name]))
    title = html.escape(f"vrsim run: {result.summary['scenario']}")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1500px}}table{{border-collapse:collapse}}
td{{padding:2px 10px;border-bottom:1px solid #ddd}}td:nth-child(2){{text-align:right}}
img{{max-width:100%}}</style>
</head><body><h1>{title}</h1>
<p>{html.escape(result.world.scenario.description)}</p>
<table>{rows}</table>
{images}
<p>Files beside this page: summary.json, track.csv, as_applied.tif, error.tif (GeoTIFF, kg/ha).</p>
</body></html>
"""
    with open(paths["report.html"], "w") as fh:
        fh.write(page)
