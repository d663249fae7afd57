"""`vrsim run [SCENARIO] [--out DIR] [--json] [--quiet]`: one field scenario, in process."""

from __future__ import annotations

import os
import sys
import time

from services.cli.options import add_input_cap, apply_input_cap

HELP = "run a field scenario (file or built-in name; default: the built-in 'default')"


def configure(parser) -> None:
    parser.add_argument("scenario", nargs="?", default=None,
                        help="scenario TOML file or built-in name (default, large)")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="output folder (default: runs/<scenario>-<time>/)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    add_input_cap(parser)


class Progress:
    """A one-line progress bar on stderr, shown once a run has taken more than a second, and only on a
    terminal (a log file gets no carriage-return noise)."""

    def __init__(self, label: str, enabled: bool):
        self.label = label
        self.enabled = enabled and sys.stderr.isatty()
        self.start = time.perf_counter()
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or time.perf_counter() - self.start < 1.0:
            return
        frac = done / total if total else 1.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} control loop [{bar:<30}] {100 * frac:5.1f} %")
        sys.stderr.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown:
            sys.stderr.write("\n")


def run(args) -> int:
    from services.outputs.summary import summary_json, text_summary
    from services.outputs.write import write_outputs
    from services.sim import run as field_run
    from services.sim import scenario

    apply_input_cap(args)
    sc = scenario.load(args.scenario)
    progress = Progress(f"vrsim run {sc.name}", enabled=not args.quiet)
    try:
        result = field_run.run(sc, progress=progress)
    finally:
        progress.close()
    safe_name = "".join(c if c.isalnum() or c in "-_." else "_" for c in sc.name)  # a name may hold "/"
    out_dir = args.out or os.path.join("runs", f"{safe_name}-{time.strftime('%Y%m%d-%H%M%S')}")
    t0 = time.perf_counter()
    write_outputs(result, out_dir)
    result.summary["outputs_wall_s"] = time.perf_counter() - t0
    result.summary["out_dir"] = out_dir
    if args.json:
        print(summary_json(result.summary))
    else:
        print(text_summary(result.summary))
        print(f"  outputs in {out_dir}/ (report.html, map.png, timeseries.png, track.csv, "
              f"as_applied.tif, error.tif, summary.json)")
    return 0
