"""`vrsim report --db MONITOR.sqlite [--run RUN_ID] --out DIR [--json]`: the files of `vrsim run` for a
run through the Zenoh services, from the monitor's database (`services.bus.monitor.recorded_run`). A run
the database does not hold whole (ticks missing, or not announced as finished) gets one warning line on
stderr; its summary says ``complete: false``, ``missing_ticks`` and ``end_reason``."""

from __future__ import annotations

import os
import sys
import time

HELP = "write a services run's report, maps, track and TimeLog from the monitor's database"


def configure(parser) -> None:
    parser.add_argument("--db", required=True, metavar="MONITOR.sqlite",
                        help="the monitor's database (vrsim serve monitor|all --db)")
    parser.add_argument("--run", metavar="RUN_ID", help="which run (default: the latest started)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def run(args) -> int:
    from vrsim.common import ServiceError
    from vrsim.services.bus.monitor import MonitorStore, recorded_run
    from vrsim.services.outputs.report import incomplete_note
    from vrsim.services.outputs.summary import summary_json, text_summary
    from vrsim.services.outputs.write import outputs_line, write_outputs
    from vrsim.services.sim.as_run import with_settings

    if not os.path.isfile(args.db):
        raise ServiceError(f"--db {args.db}: no such file")
    store = MonitorStore(args.db)
    try:
        result = recorded_run(store, store.run(args.run))
    finally:
        store.close()
    t0 = time.perf_counter()
    write_outputs(result, args.out)
    result.summary["outputs_wall_s"] = time.perf_counter() - t0
    result.summary["out_dir"] = args.out
    print(summary_json(with_settings(result)) if args.json else text_summary(result.summary))
    if not args.json:
        print(outputs_line(args.out, result.world.scenario.output.track_formats))
    note = incomplete_note(result.summary)
    if note is not None:  # the files are written all the same: they are what the monitor stored
        print(f"vrsim report: warning: {note}", file=sys.stderr)
    return 0
