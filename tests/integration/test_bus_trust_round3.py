"""Issue 41's third round on the bus, over real processes: `vrsim serve all` (secure: its router
enforces the message limit, users log in from ``.vrsim/``) on loopback, queried from this process.

- ``map/rate``: a batch at `messages.MAX_POINTS` gets its reply through the router; one point more,
  or the million points api.md once promised (a reply of ~86 MB the router dropped in silence), an
  error reply naming the limit.
- User controllers: only the files the operator named at start run; a file in a subfolder of the
  allowed folder, one added later, or one without the class is refused naming the file, and none of
  its module-level code runs (it would write a marker file).
- ``scenario/start`` replies once the run is accepted (``vrsim query`` waits long enough for it), and
  ``status`` then shows the run.
- The worst inputs of each kind the bus takes get an error reply naming what is wrong, while another
  client polls ``scenario/status`` and gets every reply (each query's deadline `STATUS_DEADLINE_S`, generous
  for a loaded machine; the longest reply is printed).

Each case prints one line (``case | result``): ``pytest -s`` shows the figures measured.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import threading
import time

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.integration.test_services_support import ServeAll, open_client, write_field_files

P, K = "vrsim", "vrsim/tractor1"
STATUS_DEADLINE_S = 30.0  # a status query's timeout; the issue asks 1 s on a quiet machine (longest printed)
REFUSAL_DEADLINE_S = 30.0  # a refusal takes milliseconds to a few seconds; generous for a busy machine
MB = 1024 * 1024
ENDED = ("finished", "failed")
MARKER = "ran.txt"  # what a user controller file's module-level code would write, had it run
CONTROLLER = pathlib.Path(ROOT, "scenarios", "my_controller.py").read_text()
USER = ('[controller]\nkind = "python"\nfile = "{file}"\nclass = "MyController"\n'
        'params = { kp_a_per_rpm = 0.002, ki_a_per_rpm_s = 0.01 }\n')
# A twin-disc spinner of 14 m driving width, its transverse pattern a catch-tray profile CSV.
SPINNER = ('[implement]\nwidth_m = 14.0\nkind = "spinner"\nsections = 2\nspread_width_m = 24.0\n'
           'throw_distance_m = 4.0\npattern = "{pattern}"\n')


def note(case: str, result: str) -> None:
    print(f"\n#41 case | {case} | {result}")


def _marked(folder: str, name: str) -> str:
    """A controller module whose module-level code writes `MARKER` in ``folder`` before its class."""
    return f"open({os.path.join(folder, name)!r}, 'w').write('ran')\n" + CONTROLLER


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    """`vrsim serve all` serving a fixed map of full-precision rates, the controller allowed the
    folder ``ctl``: ``ctl/my_controller.py``, ``ctl/noclass.py`` (module code, no class) directly in
    it, ``ctl/sub/evil.py`` (module code, then the class) in a subfolder."""
    folder = str(tmp_path_factory.mktemp("trust3"))
    files = write_field_files(folder)
    from vrsim import maps

    grid = files["grid"]
    rng = np.random.default_rng(41)
    fine = maps.Grid(100.0 + 200.0 * rng.random(grid.rates_kg_ha.shape), grid.transform, grid.crs,
                     source="fine")
    maps.write_map(fine, os.path.join(folder, "fine.tif"))
    ctl = os.path.join(folder, "ctl")
    os.makedirs(os.path.join(ctl, "sub"))
    with open(os.path.join(ctl, "my_controller.py"), "w") as fh:
        fh.write(CONTROLLER)
    with open(os.path.join(ctl, "noclass.py"), "w") as fh:
        fh.write(f"open({os.path.join(folder, MARKER)!r}, 'w').write('ran')\nclass Other:\n    pass\n")
    with open(os.path.join(ctl, "sub", "evil.py"), "w") as fh:
        fh.write(_marked(folder, MARKER))
    server = ServeAll(folder, "--map", os.path.join(folder, "fine.tif"), "--allow-user-code", ctl)
    try:
        server.wait_ready()
        server.files, server.fine = files, fine
        yield server
    finally:
        assert server.stop() == 0, server.output()


def scenario(net, extra: str = "", **changes: str) -> bytes:
    with open(net.files["scenario"]) as fh:
        text = fh.read()
    for old, new in changes.items():
        text = text.replace(old, new)
    return (text + extra).encode()


def start(net, body: bytes, timeout_s: float = 120.0):
    return net.query(f"{P}/scenario/start?source=s.toml;base_dir={net.folder}", body, timeout_s=timeout_s)


def idle(net) -> dict:
    return net.wait_status(lambda s: s["state"] in ("idle", "finished", "failed", "stopped"))


# ------------------------------------------------------------------------------------ map/rate
def test_a_map_rate_batch_at_the_limit_gets_its_reply_through_the_router_and_beyond_it_an_error(net):
    from vrsim.services.bus import messages

    fine = net.fine
    rng = np.random.default_rng(7)
    rows = rng.integers(0, fine.rows, messages.MAX_POINTS)
    cols = rng.integers(0, fine.cols, messages.MAX_POINTS)
    x = fine.transform.c + (cols + 0.5) * fine.transform.a  # cell centres: every point inside
    y = fine.transform.f + (rows + 0.5) * fine.transform.e
    t0 = time.monotonic()
    replies = list(net.session.get(f"{P}/map/rate", payload=json.dumps({"x": x.tolist(), "y": y.tolist()}),
                                   timeout=120))
    took = time.monotonic() - t0
    assert len(replies) == 1 and replies[0].ok is not None, replies
    raw = replies[0].ok.payload.to_bytes()
    got = json.loads(raw)
    assert len(got) == messages.MAX_POINTS and all(p["inside"] for p in got[:1000])
    assert got[0]["row"] == rows[0] and got[0]["col"] == cols[0]
    assert got[0]["rate_kg_ha"] == pytest.approx(fine.rates_kg_ha[rows[0], cols[0]], rel=1e-6)
    assert len(raw) < messages.MAX_RATES_REPLY_BYTES
    note(f"map/rate, {messages.MAX_POINTS:,} points inside a map of full-precision rates",
         f"reply of {len(raw) / 1e6:.1f} MB ({len(raw) / messages.MAX_POINTS:.0f} bytes a point) "
         f"in {took:.1f} s")
    for n in (messages.MAX_POINTS + 1, 1_000_000):
        body = json.dumps({"x": [float(x[0])] * n, "y": [float(y[0])] * n}).encode()
        t0 = time.monotonic()
        ok, reply = net.query(f"{P}/map/rate", body, timeout_s=REFUSAL_DEADLINE_S)  # else a "Timeout" error
        took = time.monotonic() - t0
        assert not ok and "more than 250,000 points in one query" in reply["error"], reply
        note(f"map/rate, {n:,} points", f"error reply in {took:.2f} s: {reply['error']}")
    assert net.query(f"{P}/map/info")[0]


# ------------------------------------------------------------------------------ user controllers
def test_user_code_runs_only_from_the_files_named_at_start_and_nothing_else_of_it_runs(net):
    folder, marker = net.folder, os.path.join(net.folder, MARKER)
    with open(os.path.join(folder, "ctl", "later.py"), "w") as fh:  # after the start: never listed
        fh.write(_marked(folder, MARKER))
    idle(net)
    cases = {"ctl/sub/evil.py": "user code runs only from the files this controller service was started with",
             "ctl/later.py": "user code runs only from the files this controller service was started with",
             "ctl/noclass.py": "no class 'MyController' at its top level (refused before running it)"}
    for file, needle in cases.items():
        body = scenario(net, USER.replace("{file}", file))
        ok, reply = start(net, body)
        assert not ok and os.path.join(folder, file) in reply["error"] and needle in reply["error"], reply
        # the controller service refuses it itself, whoever asks (scenario control checks it first)
        run = json.dumps({"run_id": "r-x", "scenario_text": body.decode(), "source": "s.toml",
                          "base_dir": folder, "clock": "lockstep", "speed": 1.0, "ticks_per_message": 50})
        ok, direct = net.query(f"{K}/control/load", run.encode())
        assert not ok and os.path.join(folder, file) in direct["error"] and needle in direct["error"], direct
        assert not os.path.exists(marker), file
        note(f"[controller] file = {file!r}",
             "refused, its code never ran: " + reply["error"].split(": ", 2)[2][:90])
    # the named file still loads and the run drives to its end
    ok, started = start(net, scenario(net, USER.replace("{file}", "ctl/my_controller.py")))
    assert ok and started["accepted"] is True, started
    status = net.wait_status(lambda s: s["run_id"] == started["run_id"] and s["state"] in ENDED)
    assert status["state"] == "finished" and status["ticks"] > 1000, status
    assert not os.path.exists(marker)


# ----------------------------------------------------------------------------- scenario/start
def test_scenario_start_replies_once_accepted_and_status_then_shows_the_run(net):
    idle(net)
    path = os.path.join(net.folder, "accepted.toml")
    with open(path, "wb") as fh:
        fh.write(scenario(net))
    t0 = time.monotonic()
    done = net.cli("query", "scenario/start", "--body", path, f"base_dir={net.folder}",
                   "source=accepted.toml")
    took = time.monotonic() - t0
    assert done.returncode == 0, done.stderr
    reply = json.loads(done.stdout)
    assert reply["accepted"] is True and reply["state"] == "starting", reply
    assert reply["status"] == f"{P}/scenario/status" and reply["scenario"] == "svc-small"
    ok, first = net.query(reply["status"])
    assert ok and first["accepted_run_id"] == reply["run_id"], first
    assert first["run_id"] in ("", reply["run_id"]) and first["state"] in ("starting", "running", "finished")
    status = net.wait_status(lambda s: s["run_id"] == reply["run_id"] and s["state"] in ENDED)
    assert status["state"] == "finished" and status["ticks"] > 1000, status
    note("vrsim query scenario/start --body accepted.toml",
         f"accepted in {took:.2f} s (command included); status then: {first['state']}, later finished")
    # a stop while it is still being loaded: it never drives
    ok, again = start(net, scenario(net))
    assert ok, again
    ok, stopped = net.query(f"{P}/scenario/stop")  # loading (it never drives) or driving (it stops)
    assert ok and stopped["run_id"] == again["run_id"], stopped
    status = net.wait_status(lambda s: s["accepted_run_id"] == again["run_id"]
                             and s["state"] in ("stopped", "finished"))
    assert status["state"] == "stopped", status


# ----------------------------------------------------------------------------- worst inputs
def _worst_inputs(net, tmp: str) -> dict[str, tuple[bytes, str]]:
    """{case: (scenario/start body, what the error must say)} for the worst of each input the bus
    takes: the scenario's TOML, a unit in it, and the files it may name that the third round capped
    (a catch-tray profile; a TimeLog, which the bus never decodes: refused by what it is)."""
    folder = net.folder
    headers = "".join(f"[t{i}.a.b.c]\n" for i in range(70_000))[:1_040_000]  # under the 1 MB cap
    rows = b"-11.9999990,0.12345678\n"  # 23 bytes: 2.9 M rows in 64 MB
    with open(os.path.join(folder, "tray.csv"), "wb") as fh:
        fh.write(rows * ((64 * MB - 1) // len(rows)))
    shutil.copy(os.path.join(folder, "tray.csv"), os.path.join(tmp, "tray.csv"))
    for sub in ("logs", "fifo"):  # of their own: an XML file's reader may open all its folder holds
        os.makedirs(os.path.join(folder, sub))
    with open(os.path.join(folder, "logs", "TLG00001.xml"), "w") as fh:
        fh.write('<TIM A="2024-01-01T00:00:00"><PTN A="0" B="0" D="0"/></TIM>\n')
    with open(os.path.join(folder, "logs", "TLG00001.bin"), "wb") as fh:
        fh.truncate(35 * MB)
    rules = os.path.join(folder, "fifo", "rules.toml")
    os.mkfifo(rules)
    implement = "[implement]\nwidth_m = 12.0\n"
    return {
        "70,000 dotted headers, 1.04 MB of TOML": (headers.encode(), "over 256 tables"),
        "one dotted header of 1 MB": (("[" + ".".join(["a"] * 500_000) + "]\n").encode(),
                                      "a dotted key of over 16 parts"),
        "7 MB of TOML (comments), under the body limit": (b"# x\n" * (7 * MB // 4), "cap for scenario files"),
        "[map] unit = 10**10**10 kg/ha": (scenario(net, **{'file = "map.tif"\n': 'file = "map.tif"\n'
                                                           'unit = "10**10**10 kg/ha"\n'}), "[map] unit"),
        "a spinner's catch-tray profile of 2.9 M rows (64 MB)": (
            scenario(net, **{implement: SPINNER.format(pattern="tray.csv")}), "over 10,000 rows"),
        "the same profile outside the data root": (
            scenario(net, **{implement: SPINNER.format(pattern=os.path.join(tmp, "tray.csv"))}),
            "[implement] pattern"),
        "a TimeLog (35 MB binary) named as the [map] file": (
            scenario(net, **{'file = "map.tif"': 'file = "logs/TLG00001.xml"'}), "a TimeLog"),
        "a fuzzy PID's rules_file a FIFO": (
            scenario(net, f'[controller]\nkind = "fuzzy_pid"\nparams = {{ rules_file = "{rules}" }}\n'),
            "is a FIFO, not a regular file"),
    }


class _Poller:
    """Another client (a viewer) asking ``scenario/status`` again and again: when each query went out
    and when its reply came (monotonic seconds)."""

    def __init__(self, net):
        self.session = open_client(net.endpoint, net.state, "viewer")
        self.polls: list[tuple[float, float]] = []
        self.failures: list[str] = []
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._poll, daemon=True)
        self.thread.start()

    def _poll(self) -> None:
        while not self.done.is_set():
            t0 = time.monotonic()
            replies = list(self.session.get(f"{P}/scenario/status", timeout=STATUS_DEADLINE_S))
            self.polls.append((t0, time.monotonic()))
            if len(replies) != 1 or replies[0].ok is None:  # an error, or no reply within the deadline
                self.failures.append(repr(replies))
            time.sleep(0.005)

    def waits(self, since: float = 0.0, until: float = float("inf")) -> list[float]:
        """How long each status reply took, of the queries in flight between ``since`` and ``until``."""
        return [end - t0 for t0, end in self.polls if end >= since and t0 <= until]

    def answered(self, n: int, timeout_s: float = 60.0) -> None:
        """Until ``n`` more replies have come (so the poller is running)."""
        goal = len(self.polls) + n
        deadline = time.monotonic() + timeout_s
        while len(self.polls) < goal:
            assert time.monotonic() < deadline, "scenario/status stopped answering"
            time.sleep(0.01)

    def stop(self) -> None:
        self.done.set()
        self.thread.join(timeout=60)
        self.session.close()


ROUNDS = 3  # each case sent this often


def _refused_while_asked(net, viewer, body: bytes) -> tuple[dict, float, float]:
    """Send ``body`` to scenario/start and, while it is being answered, ask scenario/status from
    ``viewer``: (the start's error JSON, how long the start took, how long the status reply took)."""
    t0 = time.monotonic()
    pending = net.session.get(f"{P}/scenario/start?source=s.toml;base_dir={net.folder}", payload=body,
                              timeout=REFUSAL_DEADLINE_S)  # sent now; its reply is read below
    [status] = list(viewer.get(f"{P}/scenario/status", timeout=STATUS_DEADLINE_S))
    asked = time.monotonic() - t0
    assert status.ok is not None, f"scenario/status beside the start: {status.err.payload.to_bytes()}"
    replies = list(pending)
    took = time.monotonic() - t0
    assert len(replies) == 1 and replies[0].ok is None, replies
    raw = replies[0].err.payload.to_bytes()
    try:
        return json.loads(raw), took, asked
    except ValueError:  # zenoh's own error: no refusal within REFUSAL_DEADLINE_S is "Timeout"
        return {"error": raw.decode("utf-8", "replace")}, took, asked


def test_the_worst_inputs_get_error_replies_while_status_keeps_answering(net, tmp_path):
    cases = _worst_inputs(net, str(tmp_path))
    idle(net)
    poller = _Poller(net)
    viewer = open_client(net.endpoint, net.state, "viewer")
    asked = []
    try:
        for case, (body, needle) in cases.items():
            took = []
            for _ in range(ROUNDS):
                poller.answered(2)
                reply, seconds, status_s = _refused_while_asked(net, viewer, body)
                took.append(seconds)
                asked.append(status_s)
                assert needle in reply["error"], (case, reply)
                assert len(reply["error"]) < 500 and "\n" not in reply["error"], reply
            note(case, f"error reply in {max(took):.3f} s at most; status asked meanwhile answered in "
                       f"{max(asked[-ROUNDS:]):.3f} s at most: {reply['error'][:80]}")
    finally:
        poller.stop()
        viewer.close()
    waits = poller.waits()
    assert not poller.failures, f"scenario/status went unanswered within {STATUS_DEADLINE_S:g} s: " \
        f"{poller.failures[:3]}"
    note("scenario/status through all the cases above",
         f"asked beside each start: the longest {max(asked):.3f} s; polled by another viewer: {len(waits)} "
         f"replies, the longest {max(waits):.3f} s, median {float(np.median(waits)):.3f} s")
    assert net.query(f"{P}/scenario/status")[1]["missing"] == []
