"""Sweep speed on Dask: the same 8 distinct runs (the built-in default scenario, seeds 1-8) on an
embedded LocalCluster of 1 worker and of 2 workers, then 1,000 controller variants through the
batched fast path on the 2 workers, in one benchmark run.

Figures:
- ``sweep_dask_speedup``: wall time on 1 worker over wall time on 2 (goal >= 1.6 on 2 cores);
- ``sweep_dask_1worker_s``, ``sweep_dask_2workers_s``: from submitting the 8 runs to the last row
  back, the workers already started and their imports done (`services.sim.sweep.run_row` tasks
  through `services.batch.driver.run_tasks`, exactly what `vrsim sweep` runs);
- ``sweep_dask_cluster_start_s``: starting the 2-worker cluster and importing the simulation on
  its workers (paid once per sweep);
- ``sweep_variants_per_s``: controller variants evaluated per second on the default scenario through
  the batched fast path on the 2-worker cluster: 1,000 PID variants (a random design over kp, ki
  and kd) planned as `vrsim sweep` plans them, cut into one part per worker
  (`services.sim.sweep.variant_groups`), each part a `run_group` task (its own drive, then its
  variants as batches, `services.sim.variants.run_variants`); from submitting the parts to the
  last row back (goal >= 16.7/s: 1,000 variants in 60 s). The cluster's start is not in it
  (``sweep_dask_cluster_start_s``), nor the planning (``sweep_variants_plan_s``: 1,000 scenarios
  parsed and checked, in this process); ``sweep_variants_wall_s`` is that wall time;
- ``sweep_variants_drive_s``: the drive of the default scenario on a worker while the other drives
  too (as the parts do), and ``sweep_variants_drive_share``: its share of that wall time;
- ``sweep_dask_2workers_overlap``: the runs' own wall times summed over the 2-worker wall time: 2.0
  when both workers ran all the time, whatever the speed of each (on a machine busy with other work
  the speedup can stay low while the overlap shows that the runs did run side by side).

    .venv/bin/python -m bench.bench_sweep

``python -m bench.bench_sweep one-process`` prints the per-variant cost of `run_variants` of 128
variants in one process instead (no Dask; not part of `run`).
"""

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

from vrsim.services.batch.driver import open_client, run_tasks
from vrsim.services.sim.sweep import parse_sweep, plan, run_group, run_row, variant_groups

SWEEP = """
scenarios = ["default"]
seeds = [1, 2, 3, 4, 5, 6, 7, 8]
"""


def _import_simulation() -> None:
    import vrsim.services.sim.run  # noqa: F401 - imports SUMO, numpy, scipy, ... once per worker


def _sweep_wall_s(client, specs, task=run_row, tag: str = "") -> tuple[float, list[dict]]:
    """(wall s, rows) of running `task` over `specs` on `client`, as `vrsim sweep` does."""
    rows = []
    workers = len(client.scheduler_info()["workers"])
    t0 = time.perf_counter()
    run_tasks(client, specs, task, key=lambda s: f"bench{tag}-{workers}-{_first(s).key}",
              on_done=lambda spec, got, error, lost: rows.extend(
                  got if isinstance(got, list) else [got or {"status": "failed", "error": error}]))
    wall_s = time.perf_counter() - t0
    failed = [r["error"] for r in rows if r["status"] != "ok"]
    if failed:
        raise RuntimeError(f"bench_sweep: {len(failed)} runs failed: {failed[0]}")
    return wall_s, rows


def _first(item):
    return item[0] if isinstance(item, tuple) else item


@contextmanager
def _cluster(workers: int) -> Iterator[tuple[object, float]]:
    """(client, start s): an embedded cluster of `workers`, started and the simulation imported."""
    t0 = time.perf_counter()
    with open_client(workers=workers, dashboard=False) as client:
        client.run(_import_simulation)
        yield client, time.perf_counter() - t0


VARIANTS = 1000
VARIANT_SWEEP = f"""
scenarios = ["default"]
design = "random"
samples = {VARIANTS}
[set]
"controller.kind" = "PID"
"controller.gains" = "manual"
[axes]
"controller.kp" = {{ min = 0.1, max = 1.5 }}
"controller.ki" = {{ min = 0.5, max = 8.0 }}
"controller.kd" = {{ min = 0.0, max = 0.02 }}
"""


def _drive_s() -> float:
    from vrsim.services.sim.run import drive
    from vrsim.services.sim.scenario import load

    t0 = time.perf_counter()
    drive(load("default"))
    return time.perf_counter() - t0


def variants_on_cluster(client) -> dict:
    """The figures of `VARIANTS` PID variants on the default scenario through the fast path."""
    t0 = time.perf_counter()
    specs = plan(parse_sweep(VARIANT_SWEEP, "bench_sweep_variants"))
    plan_s = time.perf_counter() - t0
    parts = variant_groups(specs, workers=len(client.scheduler_info()["workers"]))
    drive_s = max(client.run(_drive_s).values())   # both workers at once, as the parts drive
    wall_s, rows = _sweep_wall_s(client, parts, run_group, tag="-variants")
    assert len(rows) == VARIANTS and len({r["mae_kg_ha"] for r in rows}) > VARIANTS // 2, \
        "the variants did not all run, or do not differ"
    return {"sweep_variants_per_s": VARIANTS / wall_s, "sweep_variants_wall_s": wall_s,
            "sweep_variants_drive_s": drive_s, "sweep_variants_drive_share": drive_s / wall_s,
            "sweep_variants_plan_s": plan_s}


def variant_cost_ms(n: int = 128) -> tuple[float, float]:
    """(ms per variant, drive s): `run_variants` of `n` PID variants on the default scenario, this
    process (the batch's cost without the drive)."""
    from vrsim.services.sim.run import drive
    from vrsim.services.sim.scenario import load
    from vrsim.services.sim.variants import run_variants

    specs = plan(parse_sweep(VARIANT_SWEEP.replace(f"samples = {VARIANTS}", f"samples = {n}"), "one-process"))
    cfgs = [spec.load().controller for spec in specs]
    t0 = time.perf_counter()
    shared = drive(load("default"))
    drive_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    run_variants(shared, cfgs)
    return 1e3 * (time.perf_counter() - t0) / n, drive_s


def run() -> dict:
    specs = plan(parse_sweep(SWEEP, "bench_sweep"))
    assert len(specs) == 8
    run_row(specs[0])  # warm the SUMO network cache on disk, so neither measurement builds it
    with _cluster(1) as (client, _):
        one_s, one_rows = _sweep_wall_s(client, specs)
    with _cluster(2) as (client, start_s):
        two_s, two_rows = _sweep_wall_s(client, specs)
        variants = variants_on_cluster(client)
    by_key = {r["key"]: r["mae_kg_ha"] for r in one_rows}
    assert all(by_key[r["key"]] == r["mae_kg_ha"] for r in two_rows), "runs differ between clusters"
    return {
        **variants,
        "sweep_dask_speedup": one_s / two_s,
        "sweep_dask_1worker_s": one_s,
        "sweep_dask_2workers_s": two_s,
        "sweep_dask_cluster_start_s": start_s,
        "sweep_dask_2workers_overlap": sum(r["wall_s"] for r in two_rows) / two_s,
    }


if __name__ == "__main__":
    if sys.argv[1:] == ["one-process"]:
        ms, drive_s = variant_cost_ms()
        print(f"run_variants of 128 PID variants, one process: {ms:.1f} ms per variant "
              f"(the drive before it: {drive_s:.2f} s)")
    else:
        for key, value in run().items():
            print(f"{key:<36} {value:,.4g}")
