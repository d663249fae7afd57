"""`vrsim serve aog-rc`'s timing while a field runs in real time (docs/aog_rc.md, "Speed").

aog_rc_ack_latency_p50_ms, _p99_ms, _max_ms
                          from each PGN 32500 the app's side sends (5 a second) to the first PGN 32400
                          it receives after it (the module's answer; a 200 ms report falling in between
                          counts instead, which can only shorten the figure), over UDP on 127.0.0.1
aog_rc_report_jitter_p99_ms
                          99th percentile of |period - 200 ms| between the module's PGN 32401 reports
                          (one per report period), as the app receives them
aog_rc_flood_pps          packets per second one address sent to the modules' port meanwhile (bad CRC),
                          aiming at 100,000 for `FLOOD_S` s
aog_rc_flood_report_jitter_p99_ms
                          the report period's jitter during the flood
aog_rc_flood_rss_growth_mb
                          the service's resident memory after the flood less before it
aog_rc_flood_dropped      packets the service dropped (rate-limited or bad) during the flood

The field is a 0.22 ha rectangle (12 m, 4 sections) driven at 1 x real time; the app's side answers
AgIO's speed and sections as the app does (`services.aog.app_client.AppProduct`).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
QUIET_S = 12.0      # measured without the flood
FLOOD_S = 6.0
FLOOD_PPS = 100_000
SCENARIO = """name = "aog_bench"
seed = 3
[field]
rectangle = { width_m = 36.0, length_m = 120.0, lat = 48.2, lon = 11.6 }
headland_passes = 0
[map]
synthetic = "random_field"
cell_size_m = 2.0
params = { mean_kg_ha = 160.0, std_kg_ha = 30.0, correlation_length_m = 20.0 }
[implement]
width_m = 12.0
sections = 4
delivery_delay_s = 0.8
[output]
plots = false
html = false
"""

FLOODER = """
import socket, sys, time
host, port, pps, seconds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
packet = bytes([244, 126, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 0])   # PGN 32500, bad CRC
sent, t0 = 0, time.monotonic()
while time.monotonic() - t0 < seconds:
    due = int((time.monotonic() - t0) * pps)
    while sent < due:
        try:
            s.sendto(packet, (host, port))
        except OSError:
            pass
        sent += 1
print(sent / (time.monotonic() - t0))
"""


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _measure(client, product, seconds: float) -> tuple[list[float], list[float]]:
    """(latencies, report periods) in ms over `seconds` of the app's loop."""
    latencies, infos, pending = [], [], None
    next_send = time.monotonic()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        now = time.monotonic()
        if now >= next_send and pending is None:
            product.send(client)
            pending, next_send = time.monotonic(), now + 0.2
        for msg in client.poll(0.005):
            at = msg["at"]
            if msg["pgn"] == 32400 and pending is not None:
                latencies.append((at - pending) * 1000.0)
                pending = None
            elif msg["pgn"] == 32401:
                infos.append(at)
    periods = list(np.diff(infos) * 1000.0)
    return latencies, periods


def _jitter_p99(periods: list[float]) -> float:
    return float(np.percentile(np.abs(np.asarray(periods) - 200.0), 99)) if periods else float("nan")


def run() -> dict[str, float]:
    sys.path.insert(0, ROOT)
    from vrsim.services.aog.app_client import AppClient, AppProduct, pid_settings

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.toml")
        with open(path, "w") as fh:
            fh.write(SCENARIO)
        modules, app, agio = (("127.0.0.1", _free_port()) for _ in range(3))
        argv = [sys.executable, "-P", "-m", "vrsim.services.cli", "serve", "aog-rc", path, "--speed", "1",
                "--listen", f"127.0.0.1:{modules[1]}", "--app", f"127.0.0.1:{app[1]}",
                "--agio", f"127.0.0.1:{agio[1]}", "--out", os.path.join(tmp, "out")]
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            with AppClient(modules, app, agio) as client:
                client.send(pid_settings(0, 0))
                if not client.wait_for(lambda c: c.agio_packets > 0, 120.0):
                    raise RuntimeError(f"no AgIO packet from serve aog-rc: {proc.stderr.read()[-2000:]}")
                product = AppProduct(0, 0, 160.0, (3.0, 3.0, 3.0, 3.0), 10.0)
                _measure(client, product, 2.0)   # warm up
                latencies, periods = _measure(client, product, QUIET_S)
                status_path = os.path.join(tmp, "out", "status.json")
                with open(status_path) as fh:
                    dropped_before = json.load(fh)["dropped_total"]
                rss_before = _rss_mb(proc.pid)
                flooder = subprocess.Popen([sys.executable, "-c", FLOODER, *map(str, modules), str(FLOOD_PPS),
                                            str(FLOOD_S)], stdout=subprocess.PIPE, text=True)
                _, flood_periods = _measure(client, product, FLOOD_S)
                flood_pps = float(flooder.communicate(timeout=60)[0].strip() or "nan")
                time.sleep(1.5)
                rss_after = _rss_mb(proc.pid)
                with open(status_path) as fh:
                    dropped = json.load(fh)["dropped_total"] - dropped_before
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=120)
    lat = np.asarray(latencies)
    return {"aog_rc_ack_latency_p50_ms": float(np.percentile(lat, 50)),
            "aog_rc_ack_latency_p99_ms": float(np.percentile(lat, 99)),
            "aog_rc_ack_latency_max_ms": float(lat.max()),
            "aog_rc_report_jitter_p99_ms": _jitter_p99(periods),
            "aog_rc_flood_pps": flood_pps,
            "aog_rc_flood_report_jitter_p99_ms": _jitter_p99(flood_periods),
            "aog_rc_flood_rss_growth_mb": rss_after - rss_before,
            "aog_rc_flood_dropped": float(dropped)}


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:<40} {value:,.4g}")
