"""`vrsim sweep SWEEP.toml [--workers N] [--scheduler ADDRESS] [--out DIR] [--json] [--resume]`: the
runs of a sweep file on Dask, into results.parquet, results.csv and report.html.

Exit codes: 0 every run has a row, ok or failed; 2 bad input (one line); `EXIT_LOST` (3) some runs
were lost to the cluster (scheduler gone, worker dead, no worker for ``--no-worker-timeout``): their
rows say ``lost`` and ``--resume`` runs them again. Not 2: the input was fine, and not 1: no bug.
"""

from __future__ import annotations

import functools
import os
import sys
import time

HELP = "run a sweep file (scenarios x axes x seeds) on Dask into a results table and a report"
EXIT_LOST = 3
LARGE_PLAN_RUNS = 10_000  # a plan over this many runs is confirmed first (--yes, or y at a prompt)
# The bench's figure for one run of the default scenario on one Dask worker, s: bench/results.json's
# sweep_dask_1worker_s (15.3 s) over bench/bench_sweep.py's 8 runs.
_BENCH_S_PER_RUN = 1.9


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
    parser.add_argument("--retry-failed", action="store_true",
                        help="with --resume: run the failed runs again too (lost runs always are)")
    parser.add_argument("--no-worker-timeout", type=float, default=None, metavar="SECONDS",
                        help="end the sweep (exit 3, runs not done marked lost) after this long without "
                             "a worker on the cluster (default: wait; said on stderr after 10 s)")
    parser.add_argument("--yes", action="store_true",
                        help=f"run a plan of over {LARGE_PLAN_RUNS} runs without asking")
    parser.add_argument("--run-outputs", action="store_true",
                        help="also write every run's files (as vrsim run) into DIR/runs/<key>/")
    parser.add_argument("--no-dashboard", action="store_true", help="no Dask dashboard")
    parser.add_argument("--quiet", action="store_true", help="no progress line on stderr")


class _SweepProgress:
    """One line on stderr, on a terminal only: done/total, failures, losses, rate and time left."""

    def __init__(self, total: int, enabled: bool):
        self.total = total
        self.enabled = enabled and sys.stderr.isatty()
        self.done = self.failed = self.lost = 0
        self.start = time.perf_counter()

    def update(self, row: dict) -> None:
        self.done += 1
        self.failed += row["status"] == "failed"
        self.lost += row["status"] == "lost"
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        sys.stderr.write(f"\rvrsim sweep: {self.done}/{self.total} runs, {self.failed} failed, "
                         f"{self.lost} lost, {rate:.2f} runs/s, about {left:.0f} s left   ")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled and self.done:
            sys.stderr.write("\n")


def _run_on_dask(args, tasks_for, table, progress) -> int:
    """Run the tasks ``tasks_for(workers)`` names, ``(items, task, key, rows_of)``, on the cluster the
    options name: ``task(item)`` for every item, its rows (``rows_of(item, result, error)``) into
    `table` as each comes; returns how many workers the cluster had."""
    from vrsim.services.batch.driver import dashboard_available, open_client, run_tasks

    dashboard = dashboard_available() and not args.no_dashboard
    with open_client(args.scheduler, args.workers, dashboard, args.timeout) as client:
        workers = len(client.scheduler_info().get("workers", {}))
        items, task, key, rows_of = tasks_for(workers)
        progress.start = time.perf_counter()  # the rate counts runs, not the cluster's start
        if dashboard and not args.quiet:
            print(f"vrsim sweep: Dask dashboard at {client.dashboard_link}", file=sys.stderr)

        def on_done(item, result, error, lost):
            for row in rows_of(item, result, error, lost):
                table.add(row)
                progress.update(row)

        try:
            run_tasks(client, items, task, key=key, on_done=on_done,
                      no_worker_timeout_s=args.no_worker_timeout,
                      on_no_worker=functools.partial(_say_no_worker, args.no_worker_timeout, progress))
        finally:
            table.flush()
            progress.close()
    return workers


def _say_no_worker(timeout_s: float | None, progress: _SweepProgress, idle_s: float) -> None:
    """The one line of a cluster without a worker (`services.batch.driver.run_tasks`), below the
    progress line if one is shown."""
    if progress.enabled and progress.done:
        sys.stderr.write("\n")
    then = (f"the sweep ends if none joins within {timeout_s:g} s (--no-worker-timeout)" if timeout_s
            else "waiting for one (--no-worker-timeout SECONDS ends the sweep instead)")
    print(f"vrsim sweep: no worker on the cluster for {idle_s:.0f} s: {then}", file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def _confirm_size(runs: int, args) -> None:
    """A plan over `LARGE_PLAN_RUNS` runs: its size and estimated time, then --yes or a y at the prompt
    (on a terminal); without a terminal (CI), a `ScenarioError` saying to pass --yes."""
    from vrsim.common import ScenarioError

    if runs <= LARGE_PLAN_RUNS or args.yes:
        return
    workers = args.workers or (1 if args.scheduler else os.cpu_count() or 1)
    size = (f"the plan has {runs} runs, about {_duration(runs * _BENCH_S_PER_RUN / workers)} on "
            f"{workers} worker{'s' * (workers > 1)} (the bench's {_BENCH_S_PER_RUN:g} s per run of the "
            f"default scenario)")
    if not sys.stdin.isatty():
        raise ScenarioError(f"{size}: pass --yes to run it")
    sys.stderr.write(f"vrsim sweep: {size}. Run it? [y/N] ")
    sys.stderr.flush()
    if sys.stdin.readline().strip().lower() not in ("y", "yes"):
        raise ScenarioError("not confirmed, nothing run (--yes runs a plan this big without asking)")


def _tasks(sweep, todo, args, out_dir, workers):
    """(items, task, key, rows_of) for the runs `todo`: one task per group of controller variants, or
    per part of a group so that each of the cluster's `workers` has one (the batched fast path,
    `services.sim.sweep.run_group`), when every axis is a ``controller.*`` key and no run's own files
    are asked for; else one task per run (`run_row`)."""
    from vrsim.services.outputs.sweep_results import RunOutputs
    from vrsim.services.sim.sweep import controller_only, failed_row, run_group, run_row, variant_groups

    if controller_only(sweep) and not args.run_outputs:
        def group_rows(group, rows, error, lost):
            return rows if rows is not None else [failed_row(spec, error, lost=lost) for spec in group]

        return (variant_groups(todo, workers), run_group, lambda g: f"vrsim-group-{g[0].key}-{len(g)}",
                group_rows)

    def run_rows(spec, row, error, lost):
        return [row if row is not None else failed_row(spec, error, lost=lost)]

    task = functools.partial(run_row, after=RunOutputs(out_dir)) if args.run_outputs else run_row
    return todo, task, lambda s: f"vrsim-run-{s.key}", run_rows


def run(args) -> int:
    from vrsim.common import ScenarioError
    from vrsim.services.batch.driver import check_workers
    from vrsim.services.outputs.summary import summary_json
    from vrsim.services.outputs.sweep_report import write_sweep_report
    from vrsim.services.outputs.sweep_results import ResultsTable
    from vrsim.services.sim.sweep import load_sweep, plan, planned_runs

    if args.resume and not args.out:
        raise ScenarioError("--resume needs --out DIR: the folder of the sweep to go on with")
    if args.retry_failed and not args.resume:
        raise ScenarioError("--retry-failed needs --resume: it runs the failed runs of a sweep again")
    if args.no_worker_timeout is not None and args.no_worker_timeout <= 0:
        raise ScenarioError(f"--no-worker-timeout must be > 0 s, got {args.no_worker_timeout:g}")
    check_workers(args.workers)
    t0 = time.perf_counter()
    sweep = load_sweep(args.sweep)
    _confirm_size(planned_runs(sweep), args)
    specs = plan(sweep)
    stem = os.path.splitext(os.path.basename(args.sweep))[0]
    out_dir = args.out or os.path.join("runs", f"sweep-{stem}-{time.strftime('%Y%m%d-%H%M%S')}")
    table = ResultsTable(out_dir, resume=args.resume, retry_failed=args.retry_failed)
    done = table.done
    todo = [s for s in specs if s.key not in done]
    progress = _SweepProgress(len(todo), enabled=not args.quiet)
    tasks_for = functools.partial(_tasks, sweep, todo, args, out_dir)
    workers = _run_on_dask(args, tasks_for, table, progress) if todo else 0
    table.flush()
    report = os.path.join(out_dir, "report.html")
    write_sweep_report(table.rows, sweep, report)
    outcome = {"sweep": args.sweep, "planned": len(specs), "skipped": len(specs) - len(todo),
               "ran": progress.done, "ok": progress.done - progress.failed - progress.lost,
               "failed": progress.failed, "lost": progress.lost,
               "workers": workers, "wall_s": time.perf_counter() - t0, "out_dir": out_dir,
               "results_parquet": table.parquet, "results_csv": table.csv, "report": report}
    if args.json:
        print(summary_json(outcome))
    else:
        print(f"vrsim sweep: {outcome['planned']} runs planned, {outcome['skipped']} already done, "
              f"{outcome['ran']} run ({outcome['ok']} ok, {outcome['failed']} failed, "
              f"{outcome['lost']} lost) on {workers} workers in {outcome['wall_s']:.1f} s")
        print(f"  results: {table.parquet}, {table.csv}; report: {report}")
    if progress.lost:
        print(f"vrsim sweep: {progress.lost} runs lost to the cluster (no result; their rows say lost): "
              f"--resume --out {out_dir} runs them again", file=sys.stderr)
        return EXIT_LOST
    return 0
