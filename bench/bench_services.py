"""Zenoh services on loopback: map queries per second, a 100,000-point batch, lockstep ticks per second.

Starts `vrsim serve all` on a free port (real processes, router + five services) and measures from
this process, a zenoh client like any other program:

- ``zenoh_map_queries_per_s``: single-point ``vrsim/map/rate?x=..;y=..`` queries, 64 in flight
  (a client that waits for each reply before sending the next gets ``1e6 / zenoh_map_query_rtt_us``);
- ``zenoh_map_query_rtt_us``: one query at a time, mean round trip;
- ``zenoh_batch_100k_s``: 100,000 points in one query, from the request's bytes to the reply's bytes
  (``..._with_client_json_s`` adds the client's own JSON encoding and decoding);
- ``zenoh_lockstep_ticks_per_s``: a lockstep run of a 96 m x 200 m field (vehicle -> controller ->
  monitor, 50 ticks per message), ticks over the wall time from the first tick to the last reply;
- ``zenoh_lockstep_report_s``: the monitor's report over that run (SQLite -> arrays -> metrics);
- ``zenoh_report_loop_default_slowdown``: the built-in default scenario (177,002 ticks) in lockstep
  while a viewer asks ``report`` in a loop, its drive time over the mean of the runs before and after
  without the loop, less 1 (``zenoh_report_loop_default_alone_s``: that mean; the issue's case was
  11.4 s alone and 34.3 s with the loop, +200 %, before the reports were cached);
- ``zenoh_service_lost_shown_s``: a controller killed (SIGKILL) mid-run, until ``scenario/status``
  lists it missing (polled every 10 ms).
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time

import numpy as np

from tests.integration.test_services_support import ServeAll, write_field_files

LOCKSTEP_SCENARIO = """name = "bench-lockstep"
seed = 2
[field]
rectangle = { width_m = 96.0, length_m = 200.0, lat = 52.1, lon = 11.6 }
headland_passes = 0
[map]
synthetic = "zones"
"""


def map_queries(net, grid, n: int, in_flight: int) -> float:
    import zenoh

    rng = np.random.default_rng(1)
    w, s, e, north = grid.bounds
    xs, ys = rng.uniform(w, e, n), rng.uniform(s, north, n)
    slots, done = threading.BoundedSemaphore(in_flight), threading.Semaphore(0)
    failures = []

    def on_reply(reply):
        if reply.ok is None:
            failures.append(reply.err.payload.to_bytes())

    def on_drop():
        slots.release()
        done.release()

    t0 = time.perf_counter()
    for x, y in zip(xs.tolist(), ys.tolist(), strict=True):
        slots.acquire()
        # indirect=False: these callbacks are trivial, so run them on zenoh's own thread (no hand-off)
        net.session.get(f"vrsim/map/rate?x={x!r};y={y!r}",
                        zenoh.handlers.Callback(on_reply, on_drop, indirect=False), timeout=10)
    for _ in range(n):
        done.acquire()
    elapsed = time.perf_counter() - t0
    assert not failures, failures[:3]
    return n / elapsed


def map_rtt_us(net, grid, n: int) -> float:
    x, y = float(grid.cell_centres()[0][3]), float(grid.cell_centres()[1][3])
    t0 = time.perf_counter()
    for _ in range(n):
        ok, _ = net.query(f"vrsim/map/rate?x={x!r};y={y!r}")
        assert ok
    return (time.perf_counter() - t0) / n * 1e6


def batch_s(net, grid, n: int, repeats: int = 3) -> tuple[float, float]:
    """(query only: body bytes out to reply bytes in; client too: + JSON encode and decode), best of."""
    rng = np.random.default_rng(2)
    w, s, e, north = grid.bounds
    xs, ys = rng.uniform(w, e, n), rng.uniform(s, north, n)
    best_query = best_client = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        body = json.dumps({"x": xs.tolist(), "y": ys.tolist()}).encode()
        t1 = time.perf_counter()
        replies = list(net.session.get("vrsim/map/rate", payload=body, timeout=30))
        raw = replies[0].ok.payload.to_bytes()
        t2 = time.perf_counter()
        got = json.loads(raw)
        t3 = time.perf_counter()
        assert len(got) == n
        best_query, best_client = min(best_query, t2 - t1), min(best_client, t3 - t0)
    return best_query, best_client


def lockstep(net, folder: str) -> tuple[float, float, int]:
    ok, run = net.query(f"vrsim/scenario/start?source=bench.toml;base_dir={folder}",
                        LOCKSTEP_SCENARIO.encode())
    assert ok, run
    status = net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["state"] in ("finished", "failed")
                             and s["monitor_ticks"] == s["ticks"], timeout_s=300)
    assert status["state"] == "finished", status
    t0 = time.perf_counter()
    ok, report = net.query("vrsim/tractor1/report", timeout_s=60)
    assert ok and report["ticks"] == status["ticks"], report
    print(f"report stages: {report['stage_s']}")
    return status["ticks"] / status["drive_s"], time.perf_counter() - t0, status["ticks"]


def report_loop(net) -> dict[str, float]:
    from tests.integration.test_services_complete import default_drive_s

    before, _ = default_drive_s(net)
    looped, replies = default_drive_s(net, loop=True)
    after, _ = default_drive_s(net)
    alone = (before + after) / 2
    print(f"default scenario in lockstep: {before:.2f} s and {after:.2f} s alone, {looped:.2f} s with a "
          f"viewer looping on report ({replies})")
    return {"zenoh_report_loop_default_slowdown": looped / alone - 1,
            "zenoh_report_loop_default_alone_s": alone}


def service_lost_shown_s(net) -> float:
    """A controller killed mid-run of the realtime default scenario, until status lists it missing."""
    import signal

    ok, run = net.query("vrsim/scenario/start?clock=realtime;speed=2")
    assert ok, run
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["ticks"] >= 40)
    os.kill(net.children()["controller"], signal.SIGKILL)
    t0 = time.perf_counter()
    while True:
        ok, status = net.query("vrsim/scenario/status")
        assert ok and time.perf_counter() - t0 < 60, status
        if "controller" in status["missing"]:
            return time.perf_counter() - t0
        time.sleep(0.01)


def run() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as folder:
        files = write_field_files(folder)
        net = ServeAll(folder, "--map", files["map"])
        try:
            net.wait_ready()
            grid = files["grid"]
            map_rtt_us(net, grid, 200)  # warm-up
            figures = {
                "zenoh_map_queries_per_s": map_queries(net, grid, 20_000, 64),
                "zenoh_map_query_rtt_us": map_rtt_us(net, grid, 2000),
            }
            figures["zenoh_batch_100k_s"], figures["zenoh_batch_100k_with_client_json_s"] = \
                batch_s(net, grid, 100_000)
            ticks_per_s, report_s, ticks = lockstep(net, folder)
            figures["zenoh_lockstep_ticks_per_s"] = ticks_per_s
            figures["zenoh_lockstep_report_s"] = report_s
            figures["zenoh_lockstep_ticks"] = float(ticks)
            figures.update(report_loop(net))
            figures["zenoh_service_lost_shown_s"] = service_lost_shown_s(net)  # last: a service is killed
        finally:
            net.stop()
    return figures


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    for name, value in run().items():
        print(f"{name:<32} {value:,.4g}")
