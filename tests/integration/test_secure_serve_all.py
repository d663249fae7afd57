"""`vrsim serve all` as it runs by default (secure), probed from this separate process with plain zenoh
sessions, the way an attacker on the same machine would (issue #16): who may change what, forged
records, a monitor killed mid-run, files outside the data root, hostile files, fields and bodies, with
each service's memory read from /proc. The tests share one `vrsim serve all` and run in file order.

Each case prints one line (``case | result``) for the closing note: ``pytest -s`` shows them.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import time

import orjson
import pytest

from tests.conftest import VRSIM
from tests.integration.secure_bus import plain_config
from tests.integration.test_services_support import ServeAll, open_client, without_clock, write_field_files

P, K = "vrsim", "vrsim/tractor1"
MB = 1024 * 1024
MEMORY_BOUND_MB = 500  # issue #16: a hostile input may cost a service at most this over its baseline
CONTROL_KEYS = (f"{P}/scenario/start", f"{P}/map/load", f"{K}/control/load", f"{K}/control/step",
                f"{K}/monitor/load", f"{K}/vehicle/start", f"{P}/scenario/stop", f"{K}/vehicle/stop")
WALL = {"wall_time_s", "realtime_factor", "stage_s", "outputs_wall_s", "out_dir"}


def note(case: str, result: str) -> None:
    print(f"\n#16 case | {case} | {result}")


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("secure-all"))
    files = write_field_files(folder)
    server = ServeAll(folder)
    try:
        server.wait_ready()
        server.files = files
        server.users = {}
        server.extra = []
        yield server
    finally:
        for session in server.users.values():
            session.close()
        server.stop()
        for proc in server.extra:
            proc.terminate()
            proc.wait(timeout=20)


def user(net, name: str):
    """A plain zenoh session logged in as ``name`` with the state folder's generated configuration."""
    if name not in net.users:
        net.users[name] = open_client(net.endpoint, net.state, name)
    return net.users[name]


def ask(session, selector: str, payload: bytes | None = None, timeout_s: float = 30.0) -> list:
    """The replies, each (ok, JSON); [] when none came (the router refused the query)."""
    kwargs = {"timeout": timeout_s} | ({"payload": payload} if payload is not None else {})
    out = []
    for reply in session.get(selector, **kwargs):
        sample = reply.ok if reply.ok is not None else reply.err
        raw = sample.payload.to_bytes()
        try:
            out.append((reply.ok is not None, json.loads(raw)))
        except ValueError:  # zenoh's own error, e.g. "Timeout"
            out.append((False, {"error": raw.decode("utf-8", "replace")}))
    return out


def scenario_text(net, **changes) -> bytes:
    with open(net.files["scenario"], "rb") as fh:
        text = fh.read().decode()
    for old, new in changes.items():
        assert old in text
        text = text.replace(old, new)
    return text.encode()


def start(net, *params: str, body: bytes | None = None) -> dict:
    selector = ";".join([f"{P}/scenario/start?source=scenario.toml", *params])
    [(ok, reply)] = ask(user(net, "operator"), selector, body or scenario_text(net))
    assert ok, reply
    return reply


def finished(net, run_id: str, timeout_s: float = 120.0) -> dict:
    return net.wait_status(lambda s: s["run_id"] == run_id and s["state"] in ("finished", "failed", "stopped")
                           and s["monitor_ticks"] == s["ticks"], timeout_s=timeout_s)


def report(net, run_id: str | None = None) -> dict:
    [(ok, doc)] = ask(user(net, "operator"), f"{K}/report" + (f"?run_id={run_id}" if run_id else ""))
    assert ok, doc
    return doc


def without(doc: dict, keys) -> dict:
    return without_clock(doc, keys)


def memory_mb(pid: int) -> dict[str, float]:
    """VmRSS (now) and VmHWM (peak since the process started), MB, from /proc."""
    out = {}
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith(("VmRSS:", "VmHWM:")):
                out[line.split(":")[0]] = int(line.split()[1]) / 1024
    return out


def processes(net) -> dict[str, int]:
    """Router and services (a monitor restarted by hand is this process's child)."""
    out = {"router": net.proc.pid, **net.children()}
    for proc in net.extra:
        out["monitor"] = proc.pid
    return out


# ------------------------------------------------------------------------------------ who may do what
def test_anonymous_unknown_and_wrong_password_sessions_are_refused(net):
    import zenoh

    wrong = {"transport/auth/usrpwd/user": "operator", "transport/auth/usrpwd/password": "x" * 32}
    unknown = {"transport/auth/usrpwd/user": "mallory", "transport/auth/usrpwd/password": "x" * 32}
    for case, conf in (("anonymous", plain_config(net.endpoint)),
                       ("wrong password", plain_config(net.endpoint, **wrong)),
                       ("unknown user", plain_config(net.endpoint, **unknown))):
        with pytest.raises(zenoh.ZError):
            zenoh.open(conf).close()
            pytest.fail(f"{case}: connected")
        note(f"{case} session", "refused in the handshake (zenoh.ZError)")


def test_a_viewer_changes_nothing_and_the_operator_reaches_every_key(net):
    viewer, operator = user(net, "viewer"), user(net, "operator")
    run = start(net, "clock=realtime", "speed=5")
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["state"] == "running" and s["ticks"] > 50)
    info = ask(operator, f"{P}/map/info")
    other = scenario_text(net, **{'file = "map.tif"': 'synthetic = "uniform"'})
    forged_start = messages_run_start("forged-run", other.decode())
    bodies = {f"{P}/scenario/start": other, f"{K}/control/step": b"[]"}
    for key in CONTROL_KEYS:
        assert ask(viewer, key, bodies.get(key, forged_start), timeout_s=5) == [], key
        note(f"viewer asks {key}", "no reply: the router drops the query")
    for stream in ("pose", "shaft", "rate"):
        viewer.put(f"{K}/{stream}", forged_records(stream, run["run_id"], range(10), 999.0))
    fake = viewer.declare_queryable(f"{P}/map/rate", lambda q: q.reply(q.key_expr, b'{"fake": true}'))
    token = viewer.liveliness().declare_token(f"{P}/alive/intruder")
    try:
        status = net.wait_status(lambda s: s["ticks"] > 150)
        assert status["run_id"] == run["run_id"] and status["state"] == "running", status
        assert ask(operator, f"{P}/map/info") == info
        assert [ok for ok, _ in ask(operator, f"{P}/map/rate?x=0;y=0")] == [True]  # the real map alone
        assert "intruder" not in status["alive"]
        [(ok, refused)] = ask(operator, f"{K}/report?run_id=forged-run")
        assert not ok and "no run 'forged-run'" in refused["error"]
    finally:
        fake.undeclare()
        token.undeclare()
    note("viewer puts pose/shaft/rate, declares map/rate and a liveliness token",
         "dropped by the router: run, map, alive list and monitor unchanged")
    # the operator reaches every key (an error reply is the service's: the query got there)
    for key in CONTROL_KEYS[:-2]:
        replies = ask(operator, key, b"{}" if key != f"{P}/scenario/start" else b"not toml")
        assert len(replies) == 1 and not replies[0][0], (key, replies)
        note(f"operator asks {key} (bad body)", f"the service answers: {replies[0][1]['error'][:60]}")
    [(ok, stopped)] = ask(operator, f"{P}/scenario/stop")
    assert ok and stopped["state"] == "stopped", stopped
    [(ok, _)] = ask(operator, f"{K}/vehicle/stop")
    assert ok
    note("operator asks scenario/stop, vehicle/stop", "the run stops")
    with sqlite3.connect(net.db) as db:
        rows = db.execute("SELECT x_m FROM pose WHERE run_id = ? AND tick < 10", (run["run_id"],))
        xs = [x for (x,) in rows]
    assert len(xs) == 10 and 999.0 not in xs


def messages_run_start(run_id: str, text: str) -> bytes:
    from vrsim.services.bus.messages import RunStart

    return RunStart(run_id, text, "forged.toml", "/", "lockstep", 1.0, 50).to_json()


def forged_records(stream: str, run_id: str, ticks, value: float) -> bytes:
    """A batch of well-formed records with ``value`` in every float field."""
    from vrsim.services.bus.monitor import STREAMS

    out = []
    for tick in ticks:
        doc = {}
        for name, kind, _ in STREAMS[stream]._spec:
            doc[name] = {"run_id": run_id, "tick": tick}.get(name, True if kind is bool else value)
        out.append(doc)
    return orjson.dumps(out)


# ------------------------------------------------------------------------------------ forged records
def test_forged_records_do_not_change_a_report(net):
    run = start(net)
    done = finished(net, run["run_id"])
    before = report(net, run["run_id"])
    owners = {"pose": "vehicle", "shaft": "controller", "rate": "controller"}
    for stream, owner in owners.items():
        for name in ("viewer", "operator", "map", "scenario", "monitor"):  # not the owner: the router drops
            user(net, name).put(f"{K}/{stream}", forged_records(stream, run["run_id"], range(10_000), 0.0))
        # the owner itself: the monitor keeps the first record of each tick, and knows no made-up run
        for first in range(0, done["ticks"], 1000):
            ticks = range(first, min(first + 1000, done["ticks"]))
            user(net, owner).put(f"{K}/{stream}", forged_records(stream, run["run_id"], ticks, 0.0))
        user(net, owner).put(f"{K}/{stream}", forged_records(stream, "made-up-run", range(1000), 0.0))
    time.sleep(2.0)
    after = report(net, run["run_id"])
    assert without(after, {"stage_s"}) == without(before, {"stage_s"})
    [(ok, refused)] = ask(user(net, "operator"), f"{K}/monitor/status?run_id=made-up-run")
    assert not ok and "no run 'made-up-run'" in refused["error"]
    net.first_report = before
    note("10,000 forged shaft/rate/pose records of a finished run from 5 users; the owners' own "
         "credentials for its 2,128 stored ticks and a made-up run",
         f"report unchanged (applied_kg {after['applied_kg']:.2f}, coverage_pct {after['coverage_pct']:.2f})")


def test_forged_poses_during_a_live_run_do_not_replace_real_ones(net):
    run = start(net, "clock=realtime", "speed=20")
    status = net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["ticks"] > 400)
    stored = range(0, status["ticks"] - 100)
    user(net, "vehicle").put(f"{K}/pose", forged_records("pose", run["run_id"], stored, 5.0))
    user(net, "viewer").put(f"{K}/pose", forged_records("pose", run["run_id"], stored, 5.0))
    finished(net, run["run_id"])
    got = report(net, run["run_id"])
    clean = net.first_report  # the same scenario in lockstep, unforged: the same figures
    assert without(got, WALL) == without(clean, WALL)
    note(f"forged poses for {len(stored)} stored ticks during a live real-time run (vehicle's and viewer's "
         "credentials)", "report equals the clean run's")


# ------------------------------------------------------------------------------------ a restarted monitor
def test_a_monitor_killed_and_restarted_mid_run_reports_every_stored_tick_with_the_gap_named(net):
    run = start(net, "clock=realtime", "speed=10")
    net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["ticks"] > 300)
    os.kill(net.children()["monitor"], signal.SIGKILL)
    net.wait_status(lambda s: "monitor" in s["missing"], timeout_s=10)
    time.sleep(1.5)  # the run goes on while no monitor listens
    net.extra.append(net.serve("monitor", "--db", net.db))
    net.wait_status(lambda s: "monitor" in s["alive"], timeout_s=60)
    status = net.wait_status(lambda s: s["run_id"] == run["run_id"] and s["state"] == "finished",
                             timeout_s=120)
    time.sleep(1.0)
    [(ok, stored)] = ask(user(net, "operator"), f"{K}/monitor/status?run_id={run['run_id']}")
    assert ok, stored
    got = report(net, run["run_id"])
    gaps = got["missing_ticks"]
    missing = sum(last - first + 1 for first, last in gaps)
    assert got["ticks"] == stored["ticks"] > 0 and gaps and got["complete"] is False
    assert got["ticks"] + missing == status["ticks"]  # every tick driven is either reported or named missing
    note("monitor killed (SIGKILL) at tick > 300 of a real-time run and restarted",
         f"report covers all {got['ticks']:,} stored ticks; missing_ticks {gaps}, complete false")


# ------------------------------------------------------------------------------------ the data root
def test_files_outside_the_data_root_are_refused_without_content(net, tmp_path):
    secret = tmp_path / "secret.csv"
    secret.write_text("x,y,rate\n602000,5773000,hunter2\n")
    root = net.folder
    os.symlink(secret, os.path.join(root, "link.csv"))
    with open(os.path.join(root, "header.csv"), "w") as fh:
        fh.write("password,hunter2\n1,2\n")
    cases = {"absolute path, existing file": (str(secret), ""),
             "absolute path, missing file": (str(tmp_path / "missing.csv"), ""),
             "../ out of the root": (os.path.relpath(secret, root), ""),
             "symlink inside the root": ("link.csv", ""),
             "the state folder": (".vrsim/dictionary.txt", ""),
             "base_dir outside the root": ("secret.csv", f"base_dir={tmp_path}")}
    messages = {}
    for case, (path, param) in cases.items():
        body = scenario_text(net, **{'file = "map.tif"': f'file = "{path}"'})
        selector = f"{P}/scenario/start?source=s.toml" + (f";{param}" if param else "")
        [(ok, reply)] = ask(user(net, "operator"), selector, body)
        message = reply["error"]
        assert not ok and message.startswith("s.toml: [map] file ") and path in message, message
        assert "outside the data root" in message, message
        assert "hunter2" not in message and "operator:" not in message, message
        messages[case] = message.replace(str(tmp_path / "missing.csv"), "P").replace(str(secret), "P")
        note(f"[map] file: {case}", "refused: " + message.split(": ", 2)[-1][:70])
    assert messages["absolute path, existing file"] == messages["absolute path, missing file"]
    # map/load straight from the operator, as scenario control sends it
    info = ask(user(net, "operator"), f"{P}/map/info")
    body = scenario_text(net, **{'file = "map.tif"': f'file = "{secret}"'})
    [(ok, reply)] = ask(user(net, "operator"), f"{P}/map/load", messages_run_start("r", body.decode()))
    assert not ok and "outside the data root" in reply["error"] and "hunter2" not in reply["error"]
    assert ask(user(net, "operator"), f"{P}/map/info") == info
    # inside the root, a file's content is not quoted either
    body = scenario_text(net, **{'file = "map.tif"': 'file = "header.csv"'})
    [(ok, reply)] = ask(user(net, "operator"), f"{P}/scenario/start?source=s.toml", body)
    assert not ok and "header.csv" in reply["error"] and "hunter2" not in reply["error"], reply
    note("a CSV under the root whose header is a secret",
         "refused: " + reply["error"].split(": ", 2)[-1][:70])


# ------------------------------------------------------------------------------------ bounded input
def hostile(net) -> dict[str, bytes]:
    """Scenario bodies that name hostile files under the data root, a 1e9 m field, and deep TOML."""
    root = net.folder
    os.mkfifo(os.path.join(root, "fifo.csv"))
    os.mkfifo(os.path.join(root, "fifo.geojson"))
    cases = {"[map] file is a FIFO": scenario_text(net, **{'file = "map.tif"': 'file = "fifo.csv"'})}
    text = scenario_text(net).decode()
    rect_line = next(line for line in text.splitlines() if line.startswith("rectangle = {"))
    cases["[field] file is a FIFO"] = text.replace(rect_line, 'file = "fifo.geojson"').encode()
    for ext in (".geojson", ".json", ".csv", ".xml", ".zip", ".shp", ".tif"):
        os.symlink("/dev/zero", os.path.join(root, f"zero{ext}"))
        name = {'file = "map.tif"': f'file = "zero{ext}"'}
        cases[f"[map] file is /dev/zero as {ext}"] = scenario_text(net, **name)
    cases["a field of 1e9 x 1e9 m"] = text.replace(
        rect_line, "rectangle = { width_m = 1e9, length_m = 1e9, lat = 52.1, lon = 11.6 }").encode()
    cases["TOML arrays nested 5,000 deep"] = b"x = " + b"[" * 5000 + b"]" * 5000 + b"\n"
    return cases


def test_hostile_files_fields_and_toml_are_refused_with_memory_bounded(net):
    pids = processes(net)
    baseline = {name: memory_mb(pid)["VmRSS"] for name, pid in pids.items()}
    for case, body in hostile(net).items():
        t0 = time.monotonic()
        # refused, not read to the end: no refusal within the query's 60 s is zenoh's "Timeout" error
        [(ok, reply)] = ask(user(net, "operator"), f"{P}/scenario/start?source=s.toml", body, timeout_s=60)
        took = time.monotonic() - t0
        assert not ok and reply["error"].startswith("s.toml: "), (case, reply)
        [(ok, status)] = ask(user(net, "viewer"), f"{P}/scenario/status", timeout_s=5)
        assert ok and status["missing"] == [], status
        note(case, f"refused in {took:.2f} s: {reply['error'][8:90]}")
    grown = {name: memory_mb(pid)["VmHWM"] - baseline[name] for name, pid in pids.items()}
    assert max(grown.values()) < MEMORY_BOUND_MB, grown
    assert [ok for ok, _ in ask(user(net, "viewer"), f"{P}/map/info")] == [True]
    note("peak memory above each process's baseline over all the cases above",
         ", ".join(f"{name} {mb:+.0f} MB" for name, mb in grown.items()))


def test_a_200_mb_body_is_dropped_by_the_router_and_every_service_keeps_serving(net, tmp_path):
    pids = processes(net)
    baseline = {name: memory_mb(pid)["VmRSS"] for name, pid in pids.items()}
    t0 = time.monotonic()
    replies = ask(user(net, "operator"), f"{P}/map/rate", b" " * (200 * MB), timeout_s=5)
    took = time.monotonic() - t0
    assert replies == [] or all(not ok for ok, _ in replies), replies
    grown = {name: memory_mb(pid)["VmHWM"] - baseline[name] for name, pid in pids.items()}
    assert max(grown.values()) < MEMORY_BOUND_MB, grown
    for key in (f"{P}/map/info", f"{P}/scenario/status", f"{K}/monitor/status", f"{K}/vehicle/status",
                f"{K}/control/step"):
        [(ok, reply)] = ask(user(net, "operator"), key, b"[]" if key.endswith("step") else None)
        assert ok or reply["error"] != "Timeout", (key, reply)  # answered, maybe "no run recorded yet"
    note("a 200 MB body to map/rate from the operator",
         f"dropped by the router (no reply; the client gave up after {took:.1f} s); peak memory "
         + ", ".join(f"{name} {mb:+.0f} MB" for name, mb in grown.items()) + "; every service answers")
    # vrsim query refuses such a body itself, and never reads a device or endless input
    big = tmp_path / "big.json"
    with open(big, "wb") as fh:
        fh.truncate(200 * MB)
    for args, stdin, needle in ((("--body", str(big)), None, "is over the 64 MB cap"),
                                (("--body", "/dev/zero"), None, "/dev/zero: is a device"),
                                (("--body", "-"), "/dev/zero", "standard input holds more than")):
        t0 = time.monotonic()
        with open(stdin or os.devnull, "rb") as fh:
            done = subprocess.run([VRSIM, "query", "map/rate", *args, "--state-dir", net.state], stdin=fh,
                                  capture_output=True, timeout=60)
        err = done.stderr.decode()
        assert done.returncode == 2 and needle in err and len(err.splitlines()) == 1, err
        note(f"vrsim query --body {args[1]}" + (f" < {stdin}" if stdin else ""),
             f"exit 2 in {time.monotonic() - t0:.2f} s: {err.strip()[20:100]}")
