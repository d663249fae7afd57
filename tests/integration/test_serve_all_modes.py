"""`vrsim serve all` other than by default: TLS on loopback with certificates generated for the run, an
open bus on purpose (``--insecure``: the one place the open bus is tested), and a user's own zenoh
configuration with its own authentication reaching every child. Each case prints one line
(``#16 case | ...``) for the closing note (``pytest -s``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from tests.conftest import VRSIM
from tests.integration.secure_bus import plain_config
from tests.integration.test_secure_serve_all import MB, MEMORY_BOUND_MB, forged_records, memory_mb, note
from tests.integration.test_services_support import ServeAll, free_port, open_client, write_field_files


def one_reply(session, selector: str, payload: bytes | None = None, timeout_s: float = 30.0):
    kwargs = {"timeout": timeout_s} | ({"payload": payload} if payload is not None else {})
    replies = list(session.get(selector, **kwargs))
    assert len(replies) == 1, (selector, len(replies))
    sample = replies[0].ok if replies[0].ok is not None else replies[0].err
    return replies[0].ok is not None, json.loads(sample.payload.to_bytes())


def test_tls_on_loopback_logs_clients_in_and_refuses_plain_or_untrusting_ones(tmp_path):
    import zenoh

    server = ServeAll(str(tmp_path), "--tls", scheme="tls")
    try:
        server.wait_ready()
        ok, status = one_reply(server.session, "vrsim/scenario/status")
        assert ok and status["missing"] == [], status
        tls_files = sorted(os.listdir(os.path.join(server.state, "tls")))
        assert tls_files == ["ca.pem", "router-key.pem", "router.pem"]
        done = subprocess.run([VRSIM, "query", "scenario/status", "--state-dir", server.state],
                              capture_output=True, timeout=60)  # finds the TLS endpoint in the state folder
        assert done.returncode == 0 and json.loads(done.stdout)["missing"] == [], done.stderr
        viewer = open_client(server.endpoint, server.state, "viewer")
        try:
            assert list(viewer.get("vrsim/scenario/stop", timeout=5)) == []
        finally:
            viewer.close()
        with open(os.path.join(server.state, "operator.json5")) as fh:
            auth = json.load(fh)["transport"]["auth"]["usrpwd"]
        credentials = {"transport/auth/usrpwd/user": auth["user"],
                       "transport/auth/usrpwd/password": auth["password"]}
        plain_tcp = server.endpoint.replace("tls/", "tcp/")
        for case, conf in (("plain TCP", plain_config(plain_tcp, **credentials)),
                           ("TLS without the private CA", plain_config(server.endpoint, **credentials))):
            with pytest.raises(zenoh.ZError):
                zenoh.open(conf).close()
            note(f"TLS bus: the operator's credentials over {case}", "refused")
        note("vrsim serve all --tls", "every service up over tls/127.0.0.1; vrsim query logs in from the "
             "state folder; a viewer still cannot stop")
    finally:
        assert server.stop() == 0


def test_insecure_is_an_open_bus_with_a_warning_and_the_services_still_bound_their_input(tmp_path):
    folder = str(tmp_path)
    files = write_field_files(folder)
    # data root "/": the readers, not the root, meet the devices
    server = ServeAll(folder, "--insecure", "--data-root", "/", "--max-input-mb", "100")
    try:
        server.wait_ready()
        assert server.output().count("WARNING: --insecure: no authentication and no access control") == 1
        for pid in server.children().values():  # every child gets the options that bound its input
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                argv = fh.read().split(b"\0")
            assert argv[argv.index(b"--data-root") + 1] == b"/" and b"--max-input-mb" in argv
        assert not os.path.exists(server.state)  # no credentials made
        anonymous = server.session
        ok, _ = one_reply(anonymous, "vrsim/map/info")
        assert ok
        note("vrsim serve all --insecure", "one warning; an anonymous session may ask anything")
        # the monitor's own integrity holds on an open bus: forged records change no report
        with open(files["scenario"], "rb") as fh:
            ok, run = one_reply(anonymous, f"vrsim/scenario/start?base_dir={folder}", fh.read())
        assert ok, run
        status = server.wait_status(lambda s: s["state"] == "finished" and s["monitor_ticks"] == s["ticks"])
        ok, before = one_reply(anonymous, "vrsim/tractor1/report")
        for stream in ("pose", "shaft", "rate"):
            anonymous.put(f"vrsim/tractor1/{stream}", forged_records(stream, run["run_id"], range(1000), 0.0))
            anonymous.put(f"vrsim/tractor1/{stream}", forged_records(stream, "made-up", range(1000), 0.0))
        time.sleep(2.0)
        ok, after = one_reply(anonymous, "vrsim/tractor1/report")
        assert {k: v for k, v in after.items() if k != "stage_s"} == \
            {k: v for k, v in before.items() if k != "stage_s"}
        note("open bus: anonymous forged records of a finished run and of a made-up run",
             f"the monitor keeps the first record of each of the {status['ticks']:,} ticks: report unchanged")
        children = server.children()
        baseline = {name: memory_mb(pid)["VmRSS"] for name, pid in children.items()}
        t0 = time.monotonic()
        ok, refused = one_reply(anonymous, "vrsim/map/rate", b" " * (200 * MB), timeout_s=60)
        took = time.monotonic() - t0
        assert not ok and "a body of 209,715,200 bytes is over the 50,331,648-byte limit" in refused["error"]
        for ext in (".geojson", ".csv", ".xml", ".zip", ".shp", ".tif"):
            os.symlink("/dev/zero", os.path.join(folder, f"zero{ext}"))
            with open(files["scenario"], "rb") as fh:
                body = fh.read().replace(b'file = "map.tif"', f'file = "zero{ext}"'.encode())
            t1 = time.monotonic()
            ok, reply = one_reply(anonymous, f"vrsim/scenario/start?source=s.toml;base_dir={folder}", body)
            assert not ok and "is a device, not a regular file" in reply["error"], reply
            note(f"open bus, data root /: [map] file is /dev/zero as {ext}",
                 f"refused by the reader in {time.monotonic() - t1:.2f} s")
        grown = {name: memory_mb(pid)["VmHWM"] - baseline[name] for name, pid in children.items()}
        assert max(grown.values()) < MEMORY_BOUND_MB, grown
        ok, _ = one_reply(anonymous, "vrsim/map/info")
        assert ok
        note("open bus: a 200 MB body to map/rate",
             f"the map service refuses it by its size in {took:.2f} s: peak memory "
             + ", ".join(f"{name} {mb:+.0f} MB" for name, mb in grown.items()))
    finally:
        assert server.stop() == 0


def test_serve_all_hands_its_zenoh_config_with_user_password_auth_to_every_child(tmp_path):
    """The user's own authentication (vrsim adds none with --insecure): the children log in with the
    file's credentials, so all of them come up; a session without them is refused."""
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    dictionary = tmp_path / "users.txt"
    dictionary.write_text("alice:s3cret-pw\n")
    conf = tmp_path / "zenoh.json5"
    conf.write_text(json.dumps({
        "mode": "router", "listen": {"endpoints": [endpoint]}, "scouting": {"multicast": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": False},
                      "auth": {"usrpwd": {"user": "alice", "password": "s3cret-pw",
                                          "dictionary_file": str(dictionary)}}}}))
    log = open(tmp_path / "serve.log", "w+")
    proc = subprocess.Popen([VRSIM, "serve", "all", "--insecure", "--zenoh-config", str(conf),
                             "--db", str(tmp_path / "m.sqlite")], stdout=log, stderr=subprocess.STDOUT,
                            cwd=tmp_path)
    try:
        deadline = time.monotonic() + 90
        while "Ctrl-C stops" not in (tmp_path / "serve.log").read_text():
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "serve.log").read_text()
            time.sleep(0.2)
        alice = plain_config(endpoint, **{"transport/auth/usrpwd/user": "alice",
                                          "transport/auth/usrpwd/password": "s3cret-pw"})
        with zenoh.open(alice) as session:
            names = sorted(str(r.ok.key_expr) for r in session.liveliness().get("vrsim/alive/*", timeout=2))
        assert names == [f"vrsim/alive/{n}" for n in ("controller", "map", "monitor", "router", "scenario",
                                                       "vehicle")]
        with pytest.raises(zenoh.ZError):
            zenoh.open(plain_config(endpoint)).close()
        note("vrsim serve all --insecure --zenoh-config FILE with user/password authentication",
             "every child logs in with the file's credentials; an anonymous session is refused")
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        log.close()
