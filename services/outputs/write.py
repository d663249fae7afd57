"""Every file a run writes, in one call: summary.json, prescription.tif, as_applied.tif, error.tif,
passes.tif, track.parquet and/or track.csv (``[output] track``), taskdata/ (ISO 11783 TimeLog),
as_applied_points.gpkg, map.png, sections.png, timeseries.png and report.html."""

from __future__ import annotations

import os

from vrsim.common import MapError
from vrsim.common.written import staged
from vrsim.services.outputs.aslog import check_as_applied, write_as_applied
from vrsim.services.outputs.rasters import write_rasters
from vrsim.services.outputs.summary import summary_json
from vrsim.services.outputs.track import TRACK_FILES, TrackFiles, track_rows
from vrsim.services.sim.as_run import with_settings
from vrsim.services.sim.run import RunResult

FILES = ("summary.json", "prescription.tif", "as_applied.tif", "error.tif", "passes.tif", "map.png",
         "sections.png", "timeseries.png", "report.html")   # and the track's (`TRACK_FILES`)
PICTURES = ("map.png", "sections.png", "timeseries.png")


def outputs_line(out_dir: str, track_formats=("parquet",)) -> str:
    """The line `vrsim run` and `vrsim report` print after the summary (`track_formats`: ``[output]
    track``'s)."""
    track = "".join(f"{TRACK_FILES[f]}, " for f in track_formats)
    return (f"  outputs in {out_dir}/ (report.html, map.png, sections.png, timeseries.png, {track}"
            "prescription.tif, as_applied.tif, error.tif, passes.tif, taskdata/, as_applied_points, "
            "summary.json)")


def write_outputs(result: RunResult, out_dir: str, plotter=None, track: TrackFiles | None = None,
                  early=None) -> dict[str, str]:
    """Write every output file into `out_dir`, all of them or none (`common.written.staged`: a full
    disk or a read-only folder is a `common.MapError` naming the folder, and changes no file of
    `out_dir`); returns {name: path}.

    Parameters
    ----------
    result : RunResult
    out_dir : str
        Created if missing. A taskdata/ in it that holds anything but an earlier run's log is refused
        (`common.MapError`): a TASKDATA's files belong together and are never overwritten.
    plotter : services.outputs.plot_worker.PlotWorker, optional
        A started worker that draws the pictures while the other files are written; without one they
        are drawn here.
    track : TrackFiles, optional
        A run accounted part by part (``result.bounded``): the track files it wrote as it went into
        `out_dir`, put in place here with the rest (removed if the rest fails). None: written here from
        the run's arrays (a bounded run without them writes no track).
    early : services.outputs.early.EarlyTimeseries, optional
        `plotter`'s timeseries.png of the run, drawn as it went: if it was submitted, its bytes are
        written (the first reply due) instead of drawing it again.
    """
    from vrsim.services.outputs import plots

    paths = {name: os.path.join(out_dir, name) for name in FILES}
    output = result.world.scenario.output
    check_as_applied(out_dir)  # first: a taskdata/ of something else refuses the folder
    if not output.plots:
        for name in PICTURES:
            del paths[name]
    if not output.html:
        del paths["report.html"]
    # Everything is written into a folder of its own inside out_dir, then moved in, summary.json last:
    # a folder with a summary.json holds a whole run, and a failed write changes no file of out_dir.
    with staged(out_dir, last=("summary.json",), error=MapError) as stage:
        staged_paths = {name: os.path.join(stage, name) for name in paths}
        jobs = []
        if output.plots:  # next: the pictures take longest, in the worker
            drawn = plotter is not None and early is not None and early.submitted
            jobs = [("draw_maps", plots.map_picture(result), staged_paths["map.png"]),
                    ("draw_sections", plots.sections_picture(result), staged_paths["sections.png"])]
            for job in jobs if plotter is not None else ():
                plotter.submit(*job)
            series = ("draw_timeseries", None if drawn else plots.series_picture(result),
                      staged_paths["timeseries.png"])
            if drawn:   # its reply comes first
                jobs.insert(0, series)
            else:
                jobs.append(series)
                if plotter is not None:
                    plotter.submit(*series)
        try:
            logs = _write_files(result, stage, staged_paths, jobs, plotter)
            logs.update(_track(result, stage, track))
        except BaseException:
            _drain(plotter, jobs)  # no picture may still be drawn into the folder when it is removed
            if track is not None:
                track.abort()
            raise
    paths.update({name: os.path.join(out_dir, os.path.relpath(path, stage)) for name, path in logs.items()})
    return paths


def _write_files(result: RunResult, stage: str, paths: dict[str, str], jobs: list, plotter) -> dict[str, str]:
    """Every file into the staging folder; the as-applied log's {name: path}."""
    from vrsim.services.outputs import plots

    logs = write_as_applied(result, stage)
    with open(paths["summary.json"], "w") as fh:
        fh.write(summary_json(with_settings(result)) + "\n")
    write_rasters(result, paths["prescription.tif"], paths["as_applied.tif"], paths["error.tif"],
                  paths["passes.tif"])
    while jobs:
        drawing, picture, path = jobs.pop(0)
        if plotter is not None:
            reply = plotter.result()  # waits; what went wrong in the worker is raised here
            if isinstance(reply, bytes):  # drawn in memory as the run went (`services.outputs.early`)
                with open(path, "wb") as fh:
                    fh.write(reply)
        else:
            getattr(plots, drawing)(picture, path)
    if "report.html" in paths:
        from vrsim.services.outputs.report import write_html

        write_html(result, paths)
    return logs


def _track(result: RunResult, stage: str, track: TrackFiles | None) -> dict[str, str]:
    """The track's files: those a bounded run wrote (in place already), else written into the stage
    from the run's arrays; {name: path in `stage` or in place}."""
    if track is not None:
        return {name: os.path.join(stage, os.path.relpath(path, track.folder))
                for name, path in track.finish().items()}
    if result.bounded:
        return {}
    files = TrackFiles(result.world.field, stage, result.world.scenario.output.track_formats)
    files(track_rows(result))
    return files.finish()


def _drain(plotter, jobs: list) -> None:
    """Wait for the pictures still being drawn (their errors are the failure's own)."""
    for _ in jobs if plotter is not None else ():
        try:
            plotter.result()
        except RuntimeError:
            pass
