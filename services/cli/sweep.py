"""`vrsim sweep SWEEP.toml [--workers N] [--scheduler ADDRESS] [--out DIR] [--json] [--resume]`: the
runs of a sweep file on Dask, into results.parquet, results.csv and report.html."""

from __future__ import annotations

import functools
import os
import sys
import time

HELP = "run a sweep file (scenarios x axes x seeds) on Dask into a results table and a report"


def configure(parser) -> None:
    parser.add_argument("sweep", help="sweep TOML file (see scenarios/README.md)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes of the embedded cluster (default: the machine's cores)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="run on an existing Dask cluster (tcp://host:8786) instead")
    parser.add_argument("--timeout", type=float, default=10.0, metavar="S",
                        help="seconds to wait for the scheduler and a first worker (default 10)")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="output folder (default: runs/sweep-<name>-<time>/)")
    parser.add_argument("--json", action="store_true", help="print the outcome as one JSON object")
    parser.add_argument("--resume", action="store_true",
                        help="go on with the sweep in --out: skip runs already in its results.parquet")
    parser.add_argument("--run-outputs", action="store_true",
                        help="also write every run's files (as vrsim run) into DIR/runs/<key>/")
    parser.add_argument("--no-dashboard", action="store_true", help="no Dask dashboard")
    parser.add_argument("--quiet", action="store_true", help="no progress line on stderr")


class _SweepProgress:
    """One line on stderr, on a terminal only: done/total, failures, rate and time left."""

    def __init__(self, total: int, enabled: bool):
        self.total = total
        self.enabled = enabled and sys.stderr.isatty()
        self.done = self.failed = 0
        self.start = time.perf_counter()

    def update(self, row: dict) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        sys.stderr.write(f"\rvrsim sweep: {self.done}/{self.total} runs, {self.failed} failed, "
                         f"{rate:.2f} runs/s, about {left:.0f} s left   ")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled and self.done:
            sys.stderr.write("\n")


def _run_on_dask(args, tasks_for, table, progress) -> int:
    """Run the tasks ``tasks_for(workers)`` names, ``(items, task, key, rows_of)``, on the cluster the
    options name: ``task(item)`` for every item, its rows (``rows_of(item, result, error)``) into
    `table` as each comes; returns how many workers the cluster had."""
    from services.batch.driver import dashboard_available, open_client, run_tasks

    dashboard = dashboard_available() and not args.no_dashboard
    with open_client(args.scheduler, args.workers, dashboard, args.timeout) as client:
        workers = len(client.scheduler_info().get("workers", {}))
        items, task, key, rows_of = tasks_for(workers)
        progress.start = time.perf_counter()  # the rate counts runs, not the cluster's start
        if dashboard and not args.quiet:
            print(f"vrsim sweep: Dask dashboard at {client.dashboard_link}", file=sys.stderr)

        def on_done(item, result, error):
            for row in rows_of(item, result, error):
                table.add(row)
                progress.update(row)

        try:
            run_tasks(client, items, task, key=key, on_done=on_done)
        finally:
            table.flush()
            progress.close()
    return workers


def _tasks(sweep, todo, args, out_dir, workers):
    """(items, task, key, rows_of) for the runs `todo`: one task per group of controller variants, or
    per part of a group so that each of the cluster's `workers` has one (the batched fast path,
    `services.sim.sweep.run_group`), when every axis is a ``controller.*`` key and no run's own files
    are asked for; else one task per run (`run_row`)."""
    from services.outputs.sweep_results import RunOutputs
    from services.sim.sweep import controller_only, failed_row, run_group, run_row, variant_groups

    if controller_only(sweep) and not args.run_outputs:
        def group_rows(group, rows, error):
            return rows if rows is not None else [failed_row(spec, error) for spec in group]

        return (variant_groups(todo, workers), run_group, lambda g: f"vrsim-group-{g[0].key}-{len(g)}",
                group_rows)

    def run_rows(spec, row, error):
        return [row if row is not None else failed_row(spec, error)]

    task = functools.partial(run_row, after=RunOutputs(out_dir)) if args.run_outputs else run_row
    return todo, task, lambda s: f"vrsim-run-{s.key}", run_rows


def run(args) -> int:
    from common import ScenarioError
    from services.batch.driver import check_workers
    from services.outputs.summary import summary_json
    from services.outputs.sweep_report import write_sweep_report
    from services.outputs.sweep_results import ResultsTable
    from services.sim.sweep import load_sweep, plan

    if args.resume and not args.out:
        raise ScenarioError("--resume needs --out DIR: the folder of the sweep to go on with")
    check_workers(args.workers)
    t0 = time.perf_counter()
    sweep = load_sweep(args.sweep)
    specs = plan(sweep)
    stem = os.path.splitext(os.path.basename(args.sweep))[0]
    out_dir = args.out or os.path.join("runs", f"sweep-{stem}-{time.strftime('%Y%m%d-%H%M%S')}")
    table = ResultsTable(out_dir, resume=args.resume)
    done = table.done
    todo = [s for s in specs if s.key not in done]
    progress = _SweepProgress(len(todo), enabled=not args.quiet)
    tasks_for = functools.partial(_tasks, sweep, todo, args, out_dir)
    workers = _run_on_dask(args, tasks_for, table, progress) if todo else 0
    table.flush()
    report = os.path.join(out_dir, "report.html")
    write_sweep_report(table.rows, sweep, report)
    outcome = {"sweep": args.sweep, "planned": len(specs), "skipped": len(specs) - len(todo),
               "ran": progress.done, "ok": progress.done - progress.failed, "failed": progress.failed,
               "workers": workers, "wall_s": time.perf_counter() - t0, "out_dir": out_dir,
               "results_parquet": table.parquet, "results_csv": table.csv, "report": report}
    if args.json:
        print(summary_json(outcome))
    else:
        print(f"vrsim sweep: {outcome['planned']} runs planned, {outcome['skipped']} already done, "
              f"{outcome['ran']} run ({outcome['ok']} ok, {outcome['failed']} failed) on {workers} workers "
              f"in {outcome['wall_s']:.1f} s")
        print(f"  results: {table.parquet}, {table.csv}; report: {report}")
    return 0
