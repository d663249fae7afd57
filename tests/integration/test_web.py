"""The web service with real processes: `vrsim serve all --web` (an operator page) and a second
`vrsim serve web` started on its own (a viewer), real runs of the quick scenario, `/events` read over a
raw socket, the JSON API over HTTP, and the page in a real headless Chromium driven by Playwright.
The tests share one `serve all` and run in file order; each web service is used logged in with the
token it printed with its URL (tests/integration/test_web_trust.py: what happens without)."""

from __future__ import annotations

import contextlib
import http.client
import json
import os
import re
import socket
import subprocess
import threading
import time

import numpy as np
import pytest

from tests.conftest import ROOT, VRSIM
from tests.integration.test_services_support import ServeAll, free_port

SCENARIO = os.path.join(ROOT, "scenarios", "quick_rectangle.toml")
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
OUT = os.environ.get("VRSIM_TEST_OUT", os.path.join(ROOT, "runs", "test-out"))


# ---------------------------------------------------------------------------------------- helpers
def printed_token(output: str, port: int) -> str | None:
    """The login token a web service printed with its page's URL."""
    found = re.search(rf"page at https?://[^/\s]+:{port}/\?token=([A-Za-z0-9_-]+)", output)
    return found.group(1) if found else None


class Web:
    """HTTP to one web service on 127.0.0.1, logged in with its token (`login`): every request carries
    the session cookie and key, every POST the session's CSRF token."""

    def __init__(self, port: int):
        self.port = port
        self.base = f"http://127.0.0.1:{port}"
        self.token = self.cookie = self.key = self.csrf = None

    def login(self, token: str) -> None:
        """Open the URL with the token: the answer sets the session cookie and drops the token."""
        self.token = token
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        try:
            conn.request("GET", f"/?token={token}")
            resp = conn.getresponse()
            resp.read()
            self.key = resp.getheader("x-vrsim-key")
            assert resp.status == 303 and resp.getheader("location") == f"/#key={self.key}", resp.status
            self.cookie = resp.getheader("set-cookie").split(";")[0]
        finally:
            conn.close()
        self.csrf = self.json("/api/view")["csrf"]

    def get(self, path: str, headers: dict | None = None, timeout_s: float = 130.0) -> tuple[int, bytes, str]:
        return self.request("GET", path, headers=headers, timeout_s=timeout_s)

    def json(self, path: str):
        status, body, _ = self.get(path)
        assert status == 200, body
        return json.loads(body)

    def request(self, method: str, path: str, body: bytes | None = None,
                headers: dict | None = None, timeout_s: float = 130.0) -> tuple[int, bytes, str]:
        """One request; a reply not complete within ``timeout_s`` raises TimeoutError."""
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout_s)
        mine = {"Cookie": self.cookie} if self.cookie else {}
        if self.key:
            mine["X-Vrsim-Key"] = self.key
        if method == "POST" and self.csrf:
            mine["X-CSRF-Token"] = self.csrf
        try:
            conn.request(method, path, body=body, headers={**mine, **(headers or {})})
            resp = conn.getresponse()
            return resp.status, resp.read(), resp.getheader("content-type", "")
        finally:
            conn.close()

    def wait_up(self, output, timeout_s: float = 30.0) -> None:
        """Until the service printed its URL (``output()``: what it printed so far) and answers; then
        log in with the token."""
        deadline = time.monotonic() + timeout_s
        while True:
            token = printed_token(output(), self.port)
            try:
                if token is not None and self.get("/login")[0] == 200:
                    return self.login(token)
            except OSError:
                pass
            assert time.monotonic() < deadline, f"{self.base} not up after {timeout_s} s"
            time.sleep(0.2)


class EventStream:
    """``GET /events`` over a raw socket; a thread parses the chunked body into (time, kind, doc)."""

    def __init__(self, web: Web):
        self.events: list = []
        self.sock = socket.socket()
        self.sock.connect(("127.0.0.1", web.port))
        self.sock.sendall(f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{web.port}\r\nCookie: {web.cookie}\r\n"
                          f"X-Vrsim-Key: {web.key}\r\nAccept: text/event-stream\r\n\r\n".encode())
        self.headers = ""
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        f = self.sock.makefile("rb")
        try:
            head = []
            while (line := f.readline()) not in (b"\r\n", b""):
                head.append(line.decode())
            self.headers = "".join(head)
            buf = b""
            while True:
                size = int(f.readline().strip(), 16)
                if size == 0:
                    return
                buf += f.read(size)
                f.readline()
                while b"\n\n" in buf:
                    block, buf = buf.split(b"\n\n", 1)
                    self._event(block.decode())
        except (OSError, ValueError):
            return

    def _event(self, block: str) -> None:
        kind, data = None, None
        for line in block.split("\n"):
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: "):
                data = json.loads(line[6:])
        if kind is not None:
            self.events.append((time.monotonic(), kind, data))

    def wait_for(self, predicate, what: str, timeout_s: float = 60.0) -> dict:
        """The first event whose data matches ``predicate``, waited for until ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            found = next((d for _, _, d in list(self.events) if d is not None and predicate(d)), None)
            if found is not None:
                return found
            assert self.thread.is_alive() and time.monotonic() < deadline, \
                f"{what} within {timeout_s:g} s ({len(self.events)} events)"
            time.sleep(0.05)

    def close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        self.thread.join(timeout=5)


class PoseWatch:
    """The pose stream as the bus carries it, seen from this process: when each run's first pose came
    and how many ticks per second."""

    def __init__(self, session):
        self.first: dict[str, float] = {}
        self.ticks: list[tuple[float, int]] = []
        self.sub = session.declare_subscriber("vrsim/tractor1/pose", self._on)

    def _on(self, sample) -> None:
        now = time.monotonic()
        batch = json.loads(sample.payload.to_bytes())
        self.first.setdefault(batch[0]["run_id"], now)
        self.ticks.append((now, len(batch)))

    def ticks_per_s(self) -> float:
        (t0, _), (t1, _) = self.ticks[0], self.ticks[-1]
        return sum(n for _, n in self.ticks[1:]) / (t1 - t0)

    def close(self) -> None:
        self.sub.undeclare()


def start_run(net, clock: str = "lockstep", speed: float = 1.0) -> dict:
    with open(SCENARIO, "rb") as fh:
        text = fh.read()
    selector = (f"vrsim/scenario/start?source={SCENARIO};base_dir={os.path.dirname(SCENARIO)};"
                f"clock={clock};speed={speed}")
    ok, reply = net.query(selector, text)
    assert ok, reply
    return reply


def wait_done(net, run_id: str) -> dict:
    return net.wait_status(lambda s: s["run_id"] == run_id and s["state"] in ("finished", "stopped")
                           and s["monitor_ticks"] == s["ticks"])


def per_second_max(times: list[float]) -> int:
    """The most events in any 1 s window starting at an event."""
    times = sorted(times)
    return max((sum(1 for u in times[i:] if u < t + 1.0) for i, t in enumerate(times)), default=0)


def hello(web: Web, predicate, timeout_s: float = 30.0) -> dict:
    """The `hello` of a fresh /events connection, retried until ``predicate(doc)``."""
    deadline = time.monotonic() + timeout_s
    while True:
        stream = EventStream(web)
        try:
            while not stream.events and time.monotonic() < deadline:
                time.sleep(0.02)
        finally:
            stream.close()
        doc = stream.events[0][2] if stream.events else None
        if doc is not None and predicate(doc):
            return doc
        assert time.monotonic() < deadline, f"hello never matched: {str(doc)[:400]}"
        time.sleep(0.3)


@contextlib.contextmanager
def served_web(folder: str, *args: str):
    """`vrsim serve all --web` in `folder` (with `args` before the web options) on a free port: the
    `ServeAll` with its page as ``.web``, ready and up; stopped after, and its exit code checked.
    Processes a test adds to ``.extra`` are ended first."""
    port = free_port()
    server = ServeAll(folder, *args, "--web", "--web-listen", f"127.0.0.1:{port}")
    server.web = Web(port)
    server.folder = folder
    server.extra = []
    try:
        server.wait_ready()
        server.web.wait_up(server.output)
        yield server
    finally:
        for proc in server.extra:
            proc.terminate()
            proc.wait(timeout=15)
        rc = server.stop()
        assert rc == 0, server.output()


def open_page(browser, web):
    """A page of `browser` at the size the tests use, logged in to `web` with its token, and the
    list its JavaScript errors go to."""
    page = browser.new_page(viewport={"width": 1400, "height": 820})
    errors = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(f"{web.base}/?token={web.token}")
    return page, errors


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    with served_web(str(tmp_path_factory.mktemp("web"))) as server:
        yield server


def until(page, expression: str, timeout: float = 30_000) -> None:
    """Until ``expression`` is true in ``page`` (polled from here: Playwright's `wait_for_function`
    evaluates its predicate with `eval`, which the page's Content-Security-Policy forbids)."""
    deadline = time.monotonic() + timeout / 1000
    while not page.evaluate(expression):
        assert time.monotonic() < deadline, f"never true: {expression}"
        time.sleep(0.05)


def need_chromium() -> None:
    """Debian's Chromium, which `make test` installs; missing under CI is a failure, not a skip."""
    if not os.path.exists(CHROMIUM):
        message = f"{CHROMIUM} is missing: `make test` installs it (apt-get install chromium, as root)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)


def serve_viewer(net) -> tuple[subprocess.Popen, Web]:
    """`vrsim serve web` as a process of its own: a viewer (no --operator)."""
    port = free_port()
    log = open(os.path.join(net.folder, f"web-{port}.log"), "w")
    argv = [VRSIM, "serve", "web", "--listen", f"127.0.0.1:{port}", "--connect", net.endpoint]
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, cwd=net.folder)
    net.extra.append(proc)
    web = Web(port)

    def output() -> str:
        log.flush()
        with open(log.name) as fh:
            return fh.read()

    web.wait_up(output)
    return proc, web


# ---------------------------------------------------------------------------------------- tests
def test_page_needs_nothing_but_this_server(net):
    status, html, kind = net.web.get("/")
    assert status == 200 and kind.startswith("text/html")
    assert b'src="/static/view.js"' in html and b'href="/static/view.css"' in html
    for name in ("view.js", "view.css"):
        status, body, _ = net.web.get(f"/static/{name}")
        assert status == 200 and len(body) > 1000
    for body in (html, net.web.get("/static/view.js")[1], net.web.get("/static/view.css")[1]):
        assert b"http://" not in body and b"https://" not in body and b"//cdn" not in body


def test_api_map_is_the_map_services_info_and_the_png_has_its_grid(net):
    from PIL import Image

    ok, info = net.query("vrsim/map/info")
    assert ok and net.web.json("/api/map") == info
    deadline = time.monotonic() + 30
    while (view := net.web.json("/api/view"))["map"] is None:
        assert time.monotonic() < deadline, "no map in /api/view"
        time.sleep(0.2)
    assert view["role"] == "operator" and view["map"]["info"] == info
    grid = view["map"]["grid"]
    assert (grid["rows"], grid["cols"], grid["stride"]) == (info["rows"], info["cols"], 1)
    status, png, kind = net.web.get(view["map"]["png"])
    assert status == 200 and kind == "image/png"
    img = Image.open(__import__("io").BytesIO(png))
    assert img.size == (info["cols"], info["rows"])
    assert net.web.json("/api/status")["alive"] == ["controller", "map", "monitor", "router", "scenario",
                                                    "vehicle", "web"]


def test_events_of_the_run_come_at_most_20_a_second_while_lockstep_carries_many_more_ticks(net):
    stream = EventStream(net.web)
    watch = PoseWatch(net.session)
    try:
        stream.wait_for(lambda d: True, "no hello on /events")  # the stream is open before the run starts
        started = time.monotonic()
        run = start_run(net)
        replied = time.monotonic()  # scenario/start answers once every service has loaded the run
        done = wait_done(net, run["run_id"])
        last_tick = done["ticks"] - 1
        end = (run["run_id"], last_tick)
        stream.wait_for(lambda d: d.get("pose") and (d["pose"]["run_id"], d["pose"]["tick"]) == end,
                        f"no event with the run's last pose (tick {last_tick})")
    finally:
        watch.close()
        stream.close()
    assert "content-type: text/event-stream" in stream.headers.lower()
    first_bus = watch.first[run["run_id"]]
    of_run = [(t, k, d) for t, k, d in stream.events if d["pose"] and d["pose"]["run_id"] == run["run_id"]]
    assert of_run, "no event carried a pose of the run"
    latency_s = of_run[0][0] - first_bus
    named = next(t for t, _, d in stream.events if d["run_id"] == run["run_id"])  # from scenario/status
    times = [d["sent_unix"] for t, _, d in stream.events if t >= started]  # as they left the server
    rate_per_s, ticks_per_s = per_second_max(times), watch.ticks_per_s()
    print(f"\nfirst event with a pose {latency_s * 1000:.0f} ms after the first pose on the bus, "
          f"{(of_run[0][0] - replied) * 1000:.0f} ms after scenario/start answered (the first naming the run "
          f"{(named - replied) * 1000:.0f} ms after; it answered {replied - started:.1f} s after asking); "
          f"at most {rate_per_s} events in 1 s while the bus carried {ticks_per_s:.0f} ticks/s; "
          f"{len(times)} events over the run")
    # The server's own pacing (events of a stream leave at least FRAME_S apart, by the server's clock,
    # whatever the load): at most 20 in any second of their `sent_unix`.
    assert rate_per_s <= 20
    # Frames, not ticks: the events of the run are far fewer than the ticks the bus carried.
    assert len(of_run) < done["ticks"] / 10, (len(of_run), done["ticks"])
    seqs = [d["seq"] for _, _, d in stream.events]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    last = of_run[-1][2]
    assert last["pose"]["tick"] == last["rate"]["tick"] == last_tick


def test_report_and_status_are_the_services_own(net):
    status = net.web.json("/api/status")
    ok, report = net.query(f"vrsim/tractor1/report?run_id={status['run_id']}")
    assert ok
    mine = net.web.json(f"/api/report?run_id={status['run_id']}")
    assert {k: v for k, v in mine.items() if k != "stage_s"} == {k: v for k, v in report.items()
                                                                  if k != "stage_s"}
    code, body, _ = net.web.get("/api/report?run_id=x;y")
    assert code == 400 and b"not a run id" in body
    code, body, _ = net.web.get("/api/report?run_id=nope")
    assert code == 502 and json.loads(body)["error"].startswith("monitor: no run 'nope'")


def test_a_viewer_started_after_the_run_shows_it_from_the_monitors_records(net):
    run_id = net.web.json("/api/status")["run_id"]
    mine = hello(net.web, lambda d: d["run_id"] == run_id and d["applied"]["i"])
    _, viewer = serve_viewer(net)
    theirs = hello(viewer, lambda d: d["run_id"] == run_id and d["catchup"]["state"] == "done"
                   and d["run"].get("field"))
    ticks = net.web.json("/api/status")["ticks"]
    assert theirs["catchup"]["ticks"] == ticks
    assert theirs["applied"]["i"] == mine["applied"]["i"] and len(mine["applied"]["i"]) > 5000
    # The same samples summed in another order agree to the 0.01 kg/ha shown.
    assert np.allclose(theirs["applied"]["v"], mine["applied"]["v"], rtol=0, atol=0.011)
    assert theirs["run"]["field"] == mine["run"]["field"] and theirs["run"]["scenario"] == "quick_rectangle"
    assert len(theirs["points"]) > 100  # the charts' history from the records too
    assert viewer.json("/api/view")["role"] == "viewer"
    code, body, _ = viewer.request("POST", "/api/stop")
    assert code == 403 and b"viewer" in body


def test_operator_actions_refuse_other_sites_and_other_host_names(net):
    code, body, _ = net.web.request("POST", "/api/stop", headers={"Origin": "http://evil.example"})
    assert code == 403 and b"another site" in body
    code, _, _ = net.web.get("/", headers={"Host": "evil.example:8448"})  # DNS rebinding
    assert code == 400
    code, body, _ = net.web.request("POST", "/api/start?base_dir=/etc", b"")
    assert code == 400 and b"parameter base_dir" in body
    code, body, _ = net.web.request("POST", "/api/start", b"x" * 1_000_001)
    assert code == 413


def test_page_in_chromium_shows_a_realtime_run_and_a_viewer_catches_up_mid_run(net):
    need_chromium()
    from playwright.sync_api import sync_playwright

    os.makedirs(OUT, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page, errors = open_page(browser, net.web)
            assert page.url == net.web.base + "/"  # logged in: the token is gone from the URL
            until(page, "window.vrsimView.role === 'operator' && window.vrsimView.mapLoaded")
            # Start from the page: the quick scenario, real time at 20 x.
            page.set_input_files("#scenario", SCENARIO)
            page.select_option("#clock", "realtime")
            page.fill("#speed", "20")
            page.click("#start")
            until(page, "window.vrsimView.status && window.vrsimView.status.state === 'running' "
                                   "&& window.vrsimView.appliedCells > 0", timeout=60_000)
            state = ("() => { const s = window.vrsimView; return {moves: s.tractorMoves, "
                     "cells: s.appliedCells, points: s.points, x: s.pose.x_m, y: s.pose.y_m, draws: s.draws, "
                     "run: s.runId}; }")
            before = page.evaluate(state)
            time.sleep(3.0)
            after = page.evaluate(state)
            assert after["run"] == before["run"]
            assert after["moves"] >= before["moves"] + 20
            assert (after["x"], after["y"]) != (before["x"], before["y"])
            assert after["cells"] > before["cells"] and after["points"] > before["points"]
            assert after["draws"] > before["draws"]
            # What the canvas shows is this run's layer (the previous run's cells were cleared).
            shown = page.evaluate("[window.vrsimView.layerPixels(), window.vrsimView.appliedCells]")
            assert shown[0] == shown[1] > 0
            # A web service started now, mid-run, and a page on it: the past comes from the monitor.
            _, late = serve_viewer(net)
            viewer = browser.new_page(viewport={"width": 1400, "height": 820})
            viewer.goto(f"{late.base}/?token={late.token}")
            until(viewer, f"window.vrsimView.runId === '{after['run']}' && "
                                     "window.vrsimView.catchup && window.vrsimView.catchup.state === 'done'",
                                     timeout=60_000)
            caught = viewer.evaluate("window.vrsimView.catchup")
            assert caught["ticks"] > 0
            assert viewer.evaluate("document.getElementById('ops').hidden") is True
            time.sleep(1.5)
            path = os.path.join(OUT, "web.png")
            page.screenshot(path=path)
            print(f"\nscreenshot: {path}; viewer caught up {caught['ticks']} ticks from the monitor")
            page.click("#stop")
            until(page, "window.vrsimView.status.state === 'stopped'", timeout=30_000)
            assert errors == []
        finally:
            browser.close()
    wait_done(net, after["run"])
    theirs = hello(late, lambda d: d["run_id"] == after["run"])
    mine = hello(net.web, lambda d: d["run_id"] == after["run"])
    assert set(theirs["applied"]["i"]) == set(mine["applied"]["i"])  # the past filled in, nothing twice


def test_page_keeps_up_at_lockstep_with_at_most_20_frames_a_second(net):
    need_chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 820})
            page.goto(f"{net.web.base}/?token={net.web.token}")
            until(page, "window.vrsimView.mapLoaded")
            cpu0, t0 = chromium_cpu_s(), time.monotonic()
            frames0 = page.evaluate("window.vrsimView.frames")
            run = start_run(net)
            status = wait_done(net, run["run_id"])
            cpu1, t1 = chromium_cpu_s(), time.monotonic()
            frames = page.evaluate("window.vrsimView.frames") - frames0
            share = (cpu1 - cpu0) / (t1 - t0)
            print(f"\nlockstep run ({status['ticks'] / status['drive_s']:.0f} ticks/s) with the page open: "
                  f"{frames} frames in {t1 - t0:.1f} s, Chromium used {share * 100:.0f} % of one core")
            assert frames <= 20 * (t1 - t0) + 2  # the thinning is what keeps the browser's share low
            until(page, f"window.vrsimView.runId === '{run['run_id']}' && "
                                   "window.vrsimView.status.state === 'finished'", timeout=30_000)
        finally:
            browser.close()


def chromium_cpu_s() -> float:
    """CPU seconds (user + system) of the Chromium processes this test process started."""
    parent, comm, cpu = {}, {}, {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    head, rest = fh.read().rsplit(")", 1)
                fields = rest.split()
                pid = int(entry)
                parent[pid], comm[pid] = int(fields[1]), head.split("(", 1)[1]
                cpu[pid] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
            except (OSError, ValueError, IndexError):
                continue

    def mine(pid: int) -> bool:
        while pid > 1:
            if pid == os.getpid():
                return True
            pid = parent.get(pid, 1)
        return False

    return sum(c for pid, c in cpu.items() if "chrom" in comm[pid] and mine(pid))


def test_serve_web_refuses_a_zenoh_endpoint_as_its_listen_address():
    done = subprocess.run([VRSIM, "serve", "web", "--listen", "tcp/127.0.0.1:7448"], capture_output=True,
                          timeout=60)
    assert done.returncode == 2
    assert done.stderr.decode().startswith("vrsim serve: error: serve web: --listen 'tcp/127.0.0.1:7448': "
                                           "expected HOST:PORT")


def test_serve_web_on_a_taken_port_is_a_clear_error(net):
    done = subprocess.run([VRSIM, "serve", "web", "--listen", f"127.0.0.1:{net.web.port}", "--connect",
                           net.endpoint], capture_output=True, timeout=60)
    assert done.returncode == 2
    assert f"cannot listen on 127.0.0.1:{net.web.port}" in done.stderr.decode()
