"""Every file a run writes, in one call: summary.json, as_applied.tif, error.tif, passes.tif, track.csv,
map.png, sections.png, timeseries.png and report.html."""

from __future__ import annotations

import os

from services.outputs.plots import plot_maps, plot_sections, plot_timeseries
from services.outputs.rasters import write_rasters
from services.outputs.report import write_html
from services.outputs.summary import summary_json
from services.outputs.track_csv import write_track_csv
from services.sim.run import RunResult
from services.sim.scenario import as_dict


def write_outputs(result: RunResult, out_dir: str) -> dict[str, str]:
    """Write every output file into `out_dir`; returns {name: path}."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {name: os.path.join(out_dir, name) for name in
             ("summary.json", "as_applied.tif", "error.tif", "passes.tif", "track.csv", "map.png",
              "sections.png", "timeseries.png", "report.html")}
    doc = dict(result.summary, scenario_config=as_dict(result.world.scenario))
    with open(paths["summary.json"], "w") as fh:
        fh.write(summary_json(doc) + "\n")
    write_rasters(result, paths["as_applied.tif"], paths["error.tif"], paths["passes.tif"])
    write_track_csv(result, paths["track.csv"])
    if result.world.scenario.output.plots:
        plot_maps(result, paths["map.png"])
        plot_sections(result, paths["sections.png"])
        plot_timeseries(result, paths["timeseries.png"])
    else:
        del paths["map.png"], paths["sections.png"], paths["timeseries.png"]
    if result.world.scenario.output.html:
        write_html(result, paths)
    else:
        del paths["report.html"]
    return paths
