"""The web app's /events stream (services/bus/web/app.py) driven through ASGI in this process: a
browser that stops reading makes its stream wait, not queue frames, and its next event carries
everything it missed. (Over a real socket the kernel's buffers, megabytes on loopback, hide a
stall of seconds; here the browser's `send` blocks outright, the way uvicorn's does once its
64 KB are full.)"""

from __future__ import annotations

import asyncio
import json

from vrsim.services.bus import messages
from vrsim.services.bus.web.app import create_app
from vrsim.services.bus.web.auth import Logins
from vrsim.services.bus.web.bridge import _decode
from vrsim.services.bus.web.live import FIELDS, LiveView, ViewGrid

INFO = {"bounds": [1000.0, 5000.0, 1100.0, 5060.0], "cell_size": [2.0, 2.0], "rows": 30, "cols": 50}


class NoBus:
    """The bridge's attributes the /events route uses (no bus in this test)."""

    viewers = 0
    map_png = None
    map_scale = None


def scope(path: str, cookie: str = "", key: str = "") -> dict:
    headers = [(b"host", b"127.0.0.1:8448")] + ([(b"cookie", cookie.encode())] if cookie else [])
    headers += [(b"x-vrsim-key", key.encode())] if key else []
    return {"type": "http", "asgi": {"version": "3.0", "spec_version": "2.4"}, "http_version": "1.1",
            "method": "GET", "scheme": "http", "path": path, "raw_path": path.encode(), "query_string": b"",
            "root_path": "", "headers": headers, "server": ("127.0.0.1", 8448),
            "client": ("127.0.0.1", 50000)}


def events_of(chunks: list[bytes]) -> list[tuple[str, dict]]:
    out = []
    for block in b"".join(chunks).decode().split("\n\n"):
        lines = dict(line.split(": ", 1) for line in block.split("\n") if ": " in line)
        if "event" in lines:
            out.append((lines["event"], json.loads(lines["data"])))
    return out


async def until(condition, what: str, timeout_s: float = 60.0) -> None:
    """Until ``condition()`` holds, checked between the event loop's other tasks."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while not condition():
        assert loop.time() < deadline, f"{what} within {timeout_s:g} s"
        await asyncio.sleep(0.01)


async def stalled_browser(view: LiveView, stall_frames: int):
    logins = Logins("viewer", None, "vrsim_session")
    app = create_app(view, NoBus(), None, logins)
    life_in: asyncio.Queue = asyncio.Queue()
    life_out: list = []
    await life_in.put({"type": "lifespan.startup"})

    async def life_send(message):
        life_out.append(message["type"])

    lifespan = asyncio.create_task(app({"type": "lifespan", "asgi": {"version": "3.0"}}, life_in.get,
                                       life_send))
    while "lifespan.startup.complete" not in life_out:
        await asyncio.sleep(0.01)

    reading = asyncio.Event()
    chunks: list[bytes] = []

    async def send(message):
        if message["type"] == "http.response.body" and message["body"]:
            chunks.append(message["body"])
            if len(chunks) == 1:
                await reading.wait()  # the browser reads the hello, then nothing for a while

    async def receive():
        await asyncio.sleep(3600)  # never disconnects

    def drive(tick: int) -> None:
        pose = messages.Pose("r", tick, tick * 0.05, 1010.0 + tick * 0.1, 5030.0, 1010.0, 5030.0, 0.0, 2.5,
                             2.5, True, tick * 0.1)
        rate = messages.RateSample("r", tick, tick * 0.05, 1010.0 + tick * 0.1, 5030.0, 150.0, 160.0, 0.01,
                                   12.0, "0x3f", True, [150.0], [0.01])
        view.on_pose(_decode("pose", messages.encode_batch([pose]), FIELDS["pose"]))
        view.on_rate(_decode("rate", messages.encode_batch([rate]), FIELDS["rate"]))

    drive(0)  # the run is under way when the browser comes
    await until(lambda: view.seq >= 1, "no frame of the run's first tick")
    sid = logins.open("viewer")
    stream = asyncio.create_task(app(scope("/events", f"vrsim_session={sid}", logins.sessions[sid].key),
                                     receive, send))
    await until(lambda: chunks, "no hello on the stream")  # sent; the browser reads nothing more
    first_seq = view.seq
    for tick in range(1, stall_frames + 1):  # a run goes on: a new pose, and a frame closed for it
        seq = view.seq
        drive(tick)
        await until(lambda seq=seq: view.seq > seq, f"no frame closed for tick {tick}")
    frames_during_stall = view.seq - first_seq
    reading.set()
    await until(lambda: b"".join(chunks).count(b"\n\n") >= 2, "nothing sent once the browser read again")
    stream.cancel()
    await life_in.put({"type": "lifespan.shutdown"})
    await asyncio.wait_for(lifespan, 5)
    return events_of(chunks), frames_during_stall


def test_a_browser_that_stops_reading_skips_frames_and_then_gets_all_it_missed():
    view = LiveView()
    view.set_map(INFO, ViewGrid.from_info(INFO), 1)
    events, frames = asyncio.run(stalled_browser(view, stall_frames=20))
    kinds = [k for k, _ in events]
    assert frames == 20  # frames went on while the browser read nothing
    # The hello it stalled on, then one frame with everything since: none of the frames in between.
    assert kinds == ["hello", "frame"], kinds
    hello, frame = events[0][1], events[1][1]
    assert frame["seq"] - hello["seq"] >= frames - 2
    painted = set(hello["applied"]["i"]) | set(frame["applied"]["i"])
    assert painted == set(view.layer.since(-1)["i"])  # every cell painted meanwhile reached it
    assert frame["pose"]["tick"] == view.latest["pose"]["tick"]
    assert len(frame["points"]) >= frames - 2  # the chart points it missed, from the history
