"""Sweep speed on Dask: the same 8 distinct runs (the built-in default scenario, seeds 1-8) on an
embedded LocalCluster of 1 worker and of 2 workers, in one benchmark run.

Figures:
- ``sweep_dask_speedup``: wall time on 1 worker over wall time on 2 (goal >= 1.6 on 2 cores);
- ``sweep_dask_1worker_s``, ``sweep_dask_2workers_s``: from submitting the 8 runs to the last row
  back, the workers already started and their imports done (`services.sim.sweep.run_row` tasks
  through `services.batch.driver.run_tasks`, exactly what `vrsim sweep` runs);
- ``sweep_dask_cluster_start_s``: starting the 2-worker cluster and importing the simulation on
  its workers (paid once per sweep);
- ``sweep_variants_per_s``: controller variants evaluated per second on the default scenario through
  the batched fast path (`services.sim.variants.run_variants`: one drive, then 128 PID variants with
  their own gains as one batch), the drive included (goal >= 16.7/s: 1,000 variants in 60 s);
  ``sweep_variants_drive_s`` is that drive's share;
- ``sweep_dask_2workers_overlap``: the runs' own wall times summed over the 2-worker wall time: 2.0
  when both workers ran all the time, whatever the speed of each (on a machine busy with other work
  the speedup can stay low while the overlap shows that the runs did run side by side).

    .venv/bin/python -m bench.bench_sweep
"""

import time

from services.batch.driver import open_client, run_tasks
from services.sim.sweep import parse_sweep, plan, run_row

SWEEP = """
scenarios = ["default"]
seeds = [1, 2, 3, 4, 5, 6, 7, 8]
"""


def _import_simulation() -> None:
    import services.sim.run  # noqa: F401 - imports SUMO, numpy, scipy, ... once per worker


def _sweep_wall_s(workers: int, specs) -> tuple[float, float, list[dict]]:
    """(cluster start s, runs wall s, rows) of the specs on an embedded cluster of `workers`."""
    rows = []
    t0 = time.perf_counter()
    with open_client(workers=workers, dashboard=False) as client:
        client.run(_import_simulation)
        started = time.perf_counter()
        run_tasks(client, specs, run_row, key=lambda s: f"bench-{workers}-{s.key}",
                  on_done=lambda spec, row, error: rows.append(row or {"status": "failed", "error": error}))
        done = time.perf_counter()
    failed = [r["error"] for r in rows if r["status"] != "ok"]
    if failed:
        raise RuntimeError(f"bench_sweep: {len(failed)} runs failed: {failed[0]}")
    return started - t0, done - started, rows


VARIANTS = 128


def variants_per_s() -> tuple[float, float]:
    """(variants per second, drive s): `VARIANTS` PID variants on the default scenario, one process."""
    import numpy as np

    from controller import ControllerConfig
    from services.sim.run import drive
    from services.sim.scenario import load
    from services.sim.variants import run_variants

    rng = np.random.default_rng(1)
    cfgs = [ControllerConfig(kind="PID", gains="manual", kp=float(kp), ki=float(ki), kd=float(kd))
            for kp, ki, kd in zip(rng.uniform(0.1, 1.5, VARIANTS), rng.uniform(0.5, 8.0, VARIANTS),
                                  rng.uniform(0.0, 0.02, VARIANTS), strict=True)]
    t0 = time.perf_counter()
    shared = drive(load("default"))
    drive_s = time.perf_counter() - t0
    rows = run_variants(shared, cfgs)
    wall_s = time.perf_counter() - t0
    assert len({r["mae_kg_ha"] for r in rows}) > VARIANTS // 2, "the variants do not differ"
    return VARIANTS / wall_s, drive_s


def run() -> dict:
    per_s, drive_s = variants_per_s()
    specs = plan(parse_sweep(SWEEP, "bench_sweep"))
    assert len(specs) == 8
    run_row(specs[0])  # warm the SUMO network cache on disk, so neither measurement builds it
    _, one_s, one_rows = _sweep_wall_s(1, specs)
    start_s, two_s, two_rows = _sweep_wall_s(2, specs)
    by_key = {r["key"]: r["mae_kg_ha"] for r in one_rows}
    assert all(by_key[r["key"]] == r["mae_kg_ha"] for r in two_rows), "runs differ between clusters"
    return {
        "sweep_variants_per_s": per_s,
        "sweep_variants_drive_s": drive_s,
        "sweep_dask_speedup": one_s / two_s,
        "sweep_dask_1worker_s": one_s,
        "sweep_dask_2workers_s": two_s,
        "sweep_dask_cluster_start_s": start_s,
        "sweep_dask_2workers_overlap": sum(r["wall_s"] for r in two_rows) / two_s,
    }


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:<36} {value:,.4g}")
