"""Helpers for the services' integration tests: a field and map with known cells, a `vrsim serve all`
on a free loopback port (secure: its state folder in the folder it runs in), a zenoh client session in
the test process logged in as the operator, and child-process lookup."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import time

import numpy as np
from affine import Affine

from tests.conftest import VRSIM

# Keys of a summary whose values depend on the wall clock, not on the simulation.
WALL_KEYS = {"wall_time_s", "realtime_factor", "stage_s", "outputs_wall_s", "out_dir"}
MONITOR_KEYS = frozenset({"missing_ticks", "complete", "end_reason"})  # which ticks it lacks, how it ended
# Where a run's scenario was read from: a file's path for `vrsim run`, the name it came by over the bus.
ORIGIN_KEYS = {"source", "base_dir"}
CELL_M = 2.0
MARGIN_M = 30.0
FIELD = dict(width_m=36.0, length_m=60.0, lat=52.1, lon=11.6)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def known_rates(rows: int, cols: int) -> np.ndarray:
    """Zones of 10 m x 10 m at 150, 200 or 250 kg/ha; the north-west corner cell is nodata."""
    r, c = np.mgrid[0:rows, 0:cols]
    rates = 150.0 + 50.0 * ((r // 5 + c // 5) % 3)
    rates[0, 0] = np.nan
    return rates


def write_field_files(folder: str) -> dict:
    """map.tif (EPSG:326xx, known cells) covering the field with a margin, and scenario.toml using it."""
    from vrsim import maps
    from vrsim.vehicle import Field

    field = Field.rectangle(**FIELD)
    minx, miny, maxx, maxy = field.polygon.bounds
    x0, y0 = np.floor(minx - MARGIN_M), np.ceil(maxy + MARGIN_M)
    cols = int(np.ceil((maxx + MARGIN_M - x0) / CELL_M))
    rows = int(np.ceil((y0 - (miny - MARGIN_M)) / CELL_M))
    grid = maps.Grid(known_rates(rows, cols), Affine(CELL_M, 0.0, x0, 0.0, -CELL_M, y0), field.crs,
                     source="known")
    map_path = os.path.join(folder, "map.tif")
    maps.write_map(grid, map_path)
    scenario_path = os.path.join(folder, "scenario.toml")
    with open(scenario_path, "w") as fh:
        fh.write(f"""name = "svc-small"
seed = 3
[field]
rectangle = {json.dumps(FIELD).replace('"', '').replace(':', ' =')}
headland_passes = 0
[map]
file = "map.tif"
[implement]
width_m = 12.0
""")
    return {"map": map_path, "scenario": scenario_path, "grid": grid, "crs": field.crs}


class ServeAll:
    """`vrsim serve all [SCENARIO]` in ``folder`` (its data root, with its state folder ``.vrsim``) on a
    free port."""

    def __init__(self, folder: str, *extra: str, scheme: str = "tcp"):
        self.port = free_port()
        self.endpoint = f"{scheme}/127.0.0.1:{self.port}"
        self.folder = folder
        self.state = os.path.join(folder, ".vrsim")
        self.db = os.path.join(folder, f"monitor-{self.port}.sqlite")
        self.log = open(os.path.join(folder, f"serve-{self.port}.log"), "w+")
        argv = [VRSIM, "serve", "all", *extra, "--listen", self.endpoint, "--db", self.db]
        self.proc = subprocess.Popen(argv, stdout=self.log, stderr=subprocess.STDOUT, cwd=folder)
        self.session = None

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while "Ctrl-C stops" not in self.output():
            if self.proc.poll() is not None:
                raise AssertionError(f"vrsim serve all exited {self.proc.returncode}:\n{self.output()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"vrsim serve all not ready after {timeout_s} s:\n{self.output()}")
            time.sleep(0.1)
        self.session = open_client(self.endpoint, None if "--insecure" in self.proc.args else self.state)

    def output(self) -> str:
        self.log.flush()
        with open(self.log.name) as fh:
            return fh.read()

    def children(self) -> dict[str, int]:
        return child_services(self.proc.pid)

    def query(self, selector: str, payload: bytes | None = None, timeout_s: float = 60.0):
        """(ok, decoded JSON) of the single reply (ok False: an error reply's JSON)."""
        kwargs = {"timeout": timeout_s}
        if payload is not None:
            kwargs["payload"] = payload
        replies = list(self.session.get(selector, **kwargs))
        assert len(replies) == 1, f"{selector}: {len(replies)} replies"
        reply = replies[0]
        if reply.ok is not None:
            return True, json.loads(reply.ok.payload.to_bytes())
        return False, json.loads(reply.err.payload.to_bytes())

    def cli(self, *args: str, stdin: bytes | None = None) -> subprocess.CompletedProcess:
        """`vrsim ARGS` as the operator (``--state-dir`` of this serve all)."""
        return subprocess.run([VRSIM, *args, "--connect", self.endpoint, "--state-dir", self.state],
                              input=stdin, capture_output=True, timeout=60)

    def serve(self, name: str, *extra: str) -> subprocess.Popen:
        """`vrsim serve NAME` started by hand as a client of this router, logged in as NAME."""
        return subprocess.Popen([VRSIM, "serve", name, "--connect", self.endpoint, "--state-dir", self.state,
                                 *extra], cwd=self.folder, stderr=subprocess.DEVNULL)

    def wait_status(self, predicate, timeout_s: float = 120.0) -> dict:
        deadline = time.monotonic() + timeout_s
        while True:
            ok, status = self.query("vrsim/scenario/status")
            assert ok, status
            if predicate(status):
                return status
            assert time.monotonic() < deadline, f"status never matched: {status}"
            time.sleep(0.2)

    def stop(self, sig=signal.SIGTERM) -> int:
        if self.session is not None:
            self.session.close()
            self.session = None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # say what it was doing, and leave nothing running
            still = self.children()
            for pid in (*still.values(), self.proc.pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            self.proc.wait()
            raise AssertionError(f"vrsim serve all did not stop within 30 s of {sig!r}; its services "
                                 f"then: {still}; its output:\n{self.output()}") from None
        finally:
            self.log.close()


def open_client(endpoint: str, state: str | None = None, user: str = "operator"):
    """A plain zenoh client of ``endpoint``: logged in as ``user`` with the configuration file the state
    folder ``state`` holds for it, or anonymous (``state`` None: an insecure bus)."""
    import zenoh

    conf = zenoh.Config.from_file(os.path.join(state, f"{user}.json5")) if state else zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return zenoh.open(conf)


def child_services(parent_pid: int) -> dict[str, int]:
    """{service name: pid} of the `vrsim serve NAME` children of ``parent_pid`` (from /proc)."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            if ppid != parent_pid:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as fh:
                argv = fh.read().decode().split("\0")
        except (OSError, ValueError, IndexError):
            continue
        if "serve" in argv:
            found[argv[argv.index("serve") + 1]] = int(entry)
    return found


def pid_alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def without_clock(doc: dict, keys=WALL_KEYS) -> dict:
    """`doc` (a summary, or its ``display``) without the wall-clock figures `keys`, in its ``display``
    too: what two runs of the same scenario share."""
    out = {k: v for k, v in doc.items() if k not in keys}
    if isinstance(out.get("display"), dict):
        out["display"] = without_clock(out["display"], keys)
    return out


def assert_same_summary(got: dict, expected: dict, extra: frozenset = frozenset()) -> None:
    """`got` (the monitor's report, compare's run) has `expected`'s keys (`vrsim run --json`) plus
    `extra` (`MONITOR_KEYS` for a monitor's report) and its figures to 1e-9 relative, all but the
    wall-clock ones."""
    import math

    import pytest

    assert set(got) == set(expected) | set(extra)
    for key, want in expected.items():
        if key in WALL_KEYS:
            continue
        if isinstance(want, float) and not math.isnan(want):
            assert got[key] == pytest.approx(want, rel=1e-9, abs=1e-12), key
        elif key == "display":   # every figure as shown: the same, but for the wall-clock ones
            assert set(got[key]) == set(want)
            for name, shown in without_clock(want).items():
                assert got[key][name]["unit"] == shown["unit"], name
                value, seen = shown["value"], got[key][name]["value"]
                if isinstance(value, float):
                    assert seen == pytest.approx(value, rel=1e-9, abs=1e-12, nan_ok=True), name
                else:
                    assert seen == value, name
        elif key == "scenario_config":   # the same settings as run, wherever the scenario came from
            assert {k: v for k, v in got[key].items() if k not in ORIGIN_KEYS} == \
                {k: v for k, v in want.items() if k not in ORIGIN_KEYS}
        else:
            assert got[key] == want, key
