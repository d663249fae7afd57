"""`vrsim run [SCENARIO] [--set KEY=VALUE ...] [--out DIR] [--json] [--quiet] [--check]`: one field
scenario, in process."""

from __future__ import annotations

import gc
import os
import sys
import time

from vrsim.services.cli.options import (
    add_input_cap,
    add_overrides,
    apply_input_cap,
    load_scenario,
    warnings_as_lines,
)

# The young generation's threshold during the run, objects (Python's default: 700). The run allocates
# numpy arrays and small records, which hold no reference cycles to collect.
RUN_GC_THRESHOLD = 10_000
HELP = "run a field scenario (file or built-in name; default: the built-in 'default')"
EXIT_AT_ONCE = True  # every file is closed and the workers reaped when `run` returns (`main.console`)
# `--check`: the machine cannot apply the whole map. Not 2 (the input is fine: the run runs it, and
# under-applies) nor 0, so that a script can tell "change the machine or the speeds" from "go".
EXIT_CANNOT = 3


def configure(parser) -> None:
    parser.add_argument("scenario", nargs="?", default=None,
                        help="scenario TOML file or built-in name (default, large, huge)")
    add_overrides(parser, "override a scenario key, checked like the file's (controller.kp=0.8, "
                          "gnss.kind=dgps, seed=3); repeatable")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="output folder (default: runs/<scenario>-<time>/)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress on stderr (a bar on a terminal; else a line every 10 s)")
    parser.add_argument("--check", action="store_true",
                        help="only say whether the machine can apply the map at the working speeds, and the "
                             "highest speed at which it can; then exit (nothing is driven): 0 it can, 3 it "
                             "cannot, 2 what the run would refuse")
    add_input_cap(parser)


def default_out_dir(name: str, command: str = "") -> str:
    """``runs/[<command>-]<name>-<time>/``, the scenario's name made safe for a path (it may hold "/")."""
    safe_name = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
    prefix = f"{command}-" if command else ""
    return os.path.join("runs", f"{prefix}{safe_name}-{time.strftime('%Y%m%d-%H%M%S')}")


class Progress:
    """Progress on stderr once a run has taken more than a second: on a terminal a one-line bar
    redrawn in place; without one (a log file, a CI job, a pipe) a plain line every
    `LOG_EVERY_S` seconds, so a long run is seen to move and nothing fills the log with carriage
    returns."""

    LOG_EVERY_S = 10.0

    def __init__(self, label: str, enabled: bool):
        self.label = label
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.start = time.perf_counter()
        self.shown = False
        self.logged_s = 0.0

    def __call__(self, done: int, total: int) -> None:
        elapsed = time.perf_counter() - self.start
        if not self.enabled or elapsed < 1.0:
            return
        frac = done / total if total else 1.0
        if not self.tty:
            if elapsed - self.logged_s >= self.LOG_EVERY_S:
                self.logged_s = elapsed
                sys.stderr.write(f"{self.label}: control loop {100 * frac:5.1f} % after {elapsed:.0f} s\n")
                sys.stderr.flush()
            return
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} control loop [{bar:<30}] {100 * frac:5.1f} %")
        sys.stderr.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown:
            sys.stderr.write("\n")


def run(args) -> int:
    warnings_as_lines("run")
    if args.check:
        return _check(args)
    # SUMO's process starts first: it imports while this one does and loads the scenario.
    from vrsim.services.sim.drive_worker import DriveWorker

    # What start-up imports and loads lives until the command ends: no collection walks it, neither
    # during start-up nor after (`_started`): collections took 0.08 to 0.19 s of this process's CPU in
    # the default run, 0.03 to 0.05 s so.
    collecting, threshold = gc.isenabled(), gc.get_threshold()
    gc.disable()
    driver = DriveWorker()
    try:
        return _run(args, driver)
    finally:
        driver.close()
        gc.unfreeze()
        gc.set_threshold(*threshold)
        if collecting:
            gc.enable()


def _started() -> None:
    """Start-up is over: its objects are frozen out of the collector's reach, collection resumes."""
    gc.freeze()
    gc.set_threshold(RUN_GC_THRESHOLD)
    gc.enable()


def _run(args, driver) -> int:
    sc = _scenario(args)
    driver.drive(sc)
    # The other imports while SUMO's process plans the path and drives; among them rasterio, which the
    # GeoTIFFs are written with, not left to the first write after the drive. Not pyogrio (the
    # as-applied points'): its own copy of GDAL is some 30 MB, better taken once the drive has given
    # its rasters back (`AsApplied.finish`) than at the drive's peak, for 0.06 s of CPU.
    import vrsim.maps.geotiff  # noqa: F401
    from vrsim.services.outputs.plot_worker import PlotWorker
    from vrsim.services.sim.streamed import run_streamed
    # The pictures' process imports matplotlib meanwhile, at a low priority (`PlotWorker`).
    plotter = PlotWorker().start() if sc.output.plots else None
    progress = Progress(f"vrsim run {sc.name}", enabled=not args.quiet)
    track = early = None
    try:
        from vrsim.services.outputs.early import EarlyTimeseries
        from vrsim.services.outputs.summary import summary_json, text_summary
        from vrsim.services.outputs.track import TrackFiles
        from vrsim.services.outputs.write import outputs_line, write_outputs
        from vrsim.services.sim.as_run import with_settings

        out_dir = args.out or default_out_dir(sc.name)
        # The track is written as the run accounts it (its memory is the map's and a part's), and
        # timeseries.png drawn once its minute has been driven.
        track = TrackFiles(driver.planned[0], out_dir, sc.output.track_formats)
        early = EarlyTimeseries(plotter) if plotter is not None else None
        _started()
        try:
            result = run_streamed(sc, progress=progress, worker=driver, error_split=sc.output.html,
                                  track_sink=_sinks(track, early),
                                  on_world=early.world_built if early is not None else None)
        finally:
            progress.close()
        t0 = time.perf_counter()
        write_outputs(result, out_dir, plotter, track, early)
        track = None
    finally:
        if track is not None:
            track.abort()
        if plotter is not None:
            plotter.close()
    result.summary["outputs_wall_s"] = time.perf_counter() - t0
    result.summary["out_dir"] = out_dir
    if args.json:
        print(summary_json(with_settings(result)))
    else:
        print(result.machine_check.text(result.world.grid, result.summary.get("units", "metric")))
        print(text_summary(result.summary))
        print(outputs_line(out_dir, sc.output.track_formats))
    return 0


def _sinks(*sinks):
    """One track sink that hands each stretch's rows to each of `sinks` (None: left out)."""
    sinks = [sink for sink in sinks if sink is not None]

    def each(rows: dict) -> None:
        for sink in sinks:
            sink(rows)
    return each


def _scenario(args):
    apply_input_cap(args)
    return load_scenario(args)


def _check(args) -> int:
    """`vrsim run --check`: the machine check of the scenario's world (field and map, no driving), after
    the run's own start (`services.sim.run.start_up`: what the run refuses, exit 2 with its line);
    `EXIT_CANNOT` when the machine cannot apply the whole map."""
    import dataclasses

    from vrsim.services.outputs.summary import summary_json
    from vrsim.services.sim.display import check_display, run_units
    from vrsim.services.sim.run import check_world, start_up
    from vrsim.services.sim.world import build_world

    sc = _scenario(args)
    world = build_world(sc)
    start_up(world)
    result, units = check_world(world), run_units(world)
    if args.json:
        doc = {"scenario": sc.name, **dataclasses.asdict(result), "can_apply": result.can_apply,
               "rate_unit": world.grid.map_unit, "in_rate_unit": result.in_rate_unit(world.grid),
               "units": units, "display": check_display(result, world.grid, units)}
        print(summary_json(doc))
    else:
        print(result.text(world.grid, units))
    return 0 if result.can_apply else EXIT_CANNOT
