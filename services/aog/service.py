"""`vrsim serve aog-rc`: the rate modules (and, with a scenario, AgIO) over UDP, in real time.

One asyncio loop, one thread:

* the modules' port (28888) is read in batches of at most `DRAIN_BATCH` packets per wake-up (the clock
  runs between them); each packet is checked (`services.aog.pgn.decode`) and applied at once (no queue:
  memory does not grow with the traffic; what the kernel's bounded buffer cannot hold it drops), a bad
  one dropped and counted by reason; each source (host and port) has a token bucket (`RATE_LIMIT_PPS`),
  so a flood from one is dropped before it is parsed and the app's own packets, from its port, keep
  their budget; the table of sources is bounded (`MAX_SOURCES`). A valid 32500 is answered at once
  with that sensor's PGN 32400 (vrsim's addition: the firmware only reports every 200 ms; the app takes
  any number).
* a tick every 50 ms of simulated time (`--speed` times faster than the wall clock), scheduled on
  absolute deadlines: the modules' firmware and plant step (`services.aog.firmware.RateModule.tick`);
  every 4th tick (200 ms) each sensor's PGN 32400 and each module's 32401 go to the app, and the PID's
  samples as PGN 32402 while the app asks for them; with a field, every 2nd tick (10 Hz, AgOpenGPS's
  GPS rate) AgIO's PGNs 254, 239 and 229 from the SUMO drive (`services.aog.field.FieldRun`).

The field run ends at the end of the path, a run without one after ``--duration`` or on SIGINT/SIGTERM;
then the outputs are written (`write_outputs` given by the caller).
"""

from __future__ import annotations

import asyncio
import signal
import socket
import sys
import time
from collections import OrderedDict
from dataclasses import dataclass, field

from vrsim.common.written import written
from vrsim.services.aog import pgn
from vrsim.services.aog.firmware import LOOP_MS, REPORT_MS, RateModule
from vrsim.services.outputs.encode import dumps_text

__all__ = ["AogService", "Counters", "Endpoints", "RATE_LIMIT_PPS", "Timeline", "beyond_loopback"]

RATE_LIMIT_PPS = 2000.0   # packets per second one source (host, port) may send (the app sends a few dozen)
RATE_BURST = 200.0        # its bucket's depth
MAX_SOURCES = 256         # sources remembered (least recently seen forgotten)
DRAIN_BATCH = 256         # packets read per wake-up before the clock gets its turn
AGIO_EVERY_TICKS = 2      # 10 Hz
STATUS_EVERY_S = 1.0
RECV_BUFFER_BYTES = 256 * 1024   # the kernel's receive buffer: what a burst may queue, bounded


@dataclass(frozen=True)
class Endpoints:
    """Where the modules listen and where they and AgIO send (host, port)."""

    listen: tuple[str, int] = ("127.0.0.1", 28888)
    app: tuple[str, int] = ("127.0.0.1", 29999)
    agio: tuple[str, int] = ("127.0.0.1", 17777)


def beyond_loopback(host: str) -> bool:
    """Whether listening on `host` reaches beyond this machine."""
    import ipaddress

    try:
        return not ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host != "localhost"


@dataclass
class Counters:
    """What the service received, dropped and sent (the status file's and the report's)."""

    received: int = 0
    accepted: dict = field(default_factory=lambda: {"32500": 0, "32501": 0, "32502": 0})
    dropped: dict = field(default_factory=lambda: dict.fromkeys((*pgn.REASONS, "not_ours"), 0))
    sent: dict = field(default_factory=lambda: {"32400": 0, "32401": 0, "32402": 0, "agio": 0})
    late_ticks: int = 0

    def as_dict(self) -> dict:
        return {"received": self.received, "accepted": dict(self.accepted), "dropped": dict(self.dropped),
                "dropped_total": sum(self.dropped.values()), "sent": dict(self.sent),
                "late_ticks": self.late_ticks}


class _Bucket:
    __slots__ = ("tokens", "at")

    def __init__(self, now: float):
        self.tokens, self.at = RATE_BURST, now


class Timeline:
    """Per 50 ms tick and sensor, what the app asked and what the module did (the PID over time)."""

    COLUMNS = ("time_s", "module", "sensor", "target_upm", "applied_upm", "true_upm", "pwm", "output_pwm",
               "integral", "connected", "pid_enabled", "sections_on")

    def __init__(self, limit_rows: int = 2_000_000):
        self.rows: list[tuple] = []
        self.limit_rows = limit_rows

    def add(self, time_s: float, module: RateModule) -> None:
        if len(self.rows) >= self.limit_rows:
            return
        on = module.any_section_on()
        for i, ch in enumerate(module.sensors):
            self.rows.append((round(time_s, 3), module.module_id, i, ch.target_upm, ch.meter.upm,
                              ch.plant.flow_upm, ch.pwm, ch.output_pwm, ch.pid.integral, ch.connected,
                              ch.pid_enabled, on))


class AogService:
    """The modules, their sockets and their clock.

    Parameters
    ----------
    modules : list of RateModule
    endpoints : Endpoints
    speed : float
        Simulated time per wall time.
    field_run : services.aog.field.FieldRun, optional
        With a field: AgIO's PGNs from its drive, and the drives' revolutions recorded into it (sensor
        d of the first modules, in order, drives the machine's drive d).
    duration_s : float, optional
        Stop after this much simulated time (a run without a field; None: until a signal).
    status_path : str, optional
        A JSON file rewritten every second with the counters and each sensor's state.
    ack : bool
        Answer each valid 32500 at once with the sensor's 32400.
    """

    def __init__(self, modules: list[RateModule], endpoints: Endpoints = Endpoints(), speed: float = 1.0,
                 field_run=None, duration_s: float | None = None, status_path: str | None = None,
                 ack: bool = True):
        self.modules = {m.module_id: m for m in modules}
        self.endpoints, self.speed, self.field, self.ack = endpoints, speed, field_run, ack
        self.duration_s, self.status_path = duration_s, status_path
        self.counters = Counters()
        self.timeline = Timeline()
        self.tick = 0
        self._sources: OrderedDict = OrderedDict()
        self._drives = [ch for m in modules for ch in m.sensors][:field_run.drives] if field_run else []
        self._t0 = 0.0
        self._sock = self._agio = None
        self._stop: asyncio.Event | None = None
        self.ended = "running"

    # -- receiving -----------------------------------------------------------------------------------------
    def _drain(self) -> None:
        """Read what the socket holds, at most `DRAIN_BATCH` packets, then let the clock run."""
        recv = self._sock.recvfrom
        for _ in range(DRAIN_BATCH):
            try:
                data, addr = recv(2048)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:   # an ICMP error queued on the socket: nothing to read this time
                return
            self.datagram(data, addr)

    def datagram(self, data: bytes, addr) -> None:
        """Take one packet from `addr` (never raises on its content)."""
        c = self.counters
        c.received += 1
        if not self._allowed(addr):
            c.dropped["rate_limited"] += 1
            return
        try:
            message = pgn.decode(data)
        except pgn.Rejected as exc:
            c.dropped[exc.reason] += 1
            return
        module = self.modules.get(message.module)
        if module is None:
            c.dropped["not_ours"] += 1
            return
        if not isinstance(message, pgn.RelayCommand) and not module.has_sensor(message.sensor):
            c.dropped["sensor_id"] += 1
            return
        module.apply(message, self.tick * LOOP_MS)   # the firmware's millis() as it reads it
        key = {pgn.RateCommand: "32500", pgn.RelayCommand: "32501", pgn.PidSettings: "32502"}[type(message)]
        c.accepted[key] += 1
        if self.ack and isinstance(message, pgn.RateCommand):
            self._send(pgn.encode_rate_report(module.reports()[message.sensor]), "32400")

    def _allowed(self, source) -> bool:
        """The token bucket of `source` (host, port: the app sends from a port of its own) has a token."""
        now = time.monotonic()
        bucket = self._sources.get(source)
        if bucket is None:
            bucket = self._sources[source] = _Bucket(now)
            if len(self._sources) > MAX_SOURCES:
                self._sources.popitem(last=False)
        else:
            self._sources.move_to_end(source)
            bucket.tokens = min(RATE_BURST, bucket.tokens + (now - bucket.at) * RATE_LIMIT_PPS)
            bucket.at = now
        if bucket.tokens < 1.0:
            return False
        bucket.tokens -= 1.0
        return True

    # -- sending -------------------------------------------------------------------------------------------
    def _send(self, data: bytes, kind: str, to=None) -> None:
        try:
            (self._agio if kind == "agio" else self._sock).sendto(data, to or self.endpoints.app)
        except (BlockingIOError, OSError):   # a full buffer or nobody listening: the next report follows
            return
        self.counters.sent[kind] += 1

    def _reports(self) -> None:
        for module in self.modules.values():
            for report in module.reports():
                self._send(pgn.encode_rate_report(report), "32400")
            self._send(pgn.encode_module_info(pgn.ModuleInfo(module.module_id)), "32401")

    # -- ticking -------------------------------------------------------------------------------------------
    def step(self) -> bool:
        """One 50 ms tick of simulated time; False once the run is over."""
        k = self.tick
        now_ms = k * LOOP_MS
        if self.field is not None:
            if k >= self.field.ticks:
                self.ended = "end of the path"
                return False
            if k % AGIO_EVERY_TICKS == 0:
                for message in self.field.agio(k):
                    self._send(_AGIO_ENCODERS[type(message)](message), "agio", self.endpoints.agio)
        elif self.duration_s is not None and now_ms >= self.duration_s * 1000.0:
            self.ended = "duration"
            return False
        for module in self.modules.values():
            module.tick(now_ms)
            self.timeline.add(now_ms / 1000.0, module)
            for log in module.pid_logs():
                self._send(pgn.encode_pid_log(log), "32402")
        for d, ch in enumerate(self._drives):
            p = ch.plant
            self.field.record(k, d, ch.target_upm, p.shaft_rev, p.shaft_rpm, p.current_a)
        if k % (REPORT_MS // LOOP_MS) == 0:
            self._reports()
        self.tick += 1
        return True

    async def _ticking(self) -> None:
        period = LOOP_MS / 1000.0 / self.speed
        while not self._stop.is_set():
            if not self.step():
                break
            deadline = self._t0 + self.tick * period
            delay = deadline - time.monotonic()
            if delay < -period:
                self.counters.late_ticks += 1
            if delay > 0:
                try:
                    await asyncio.wait_for(self._stop.wait(), timeout=delay)
                except asyncio.TimeoutError:
                    pass
            else:
                await asyncio.sleep(0)   # the packets waiting get their turn
        self._stop.set()

    async def _status(self) -> None:
        while not self._stop.is_set():
            self.write_status()
            try:
                await asyncio.wait_for(self._stop.wait(), timeout=STATUS_EVERY_S)
            except asyncio.TimeoutError:
                pass

    def status(self) -> dict:
        """The counters and each sensor's state now."""
        sensors = [{"module": m.module_id, "sensor": i, "target_upm": ch.target_upm,
                    "applied_upm": ch.meter.upm,
                    "pwm": ch.pwm, "flow_upm": ch.plant.flow_upm, "connected": ch.connected,
                    "pid_enabled": ch.pid_enabled,
                    "quantity": ch.meter.quantity(ch.meter_cal)}
                   for m in self.modules.values() for i, ch in enumerate(m.sensors)]
        return {"sim_time_s": self.tick * LOOP_MS / 1000.0, "ended": self.ended, **self.counters.as_dict(),
                "sensors": sensors}

    def write_status(self) -> None:
        if self.status_path is None:
            return
        with written(self.status_path) as temp, open(temp, "w") as fh:
            fh.write(dumps_text(self.status()))

    # -- running -------------------------------------------------------------------------------------------
    def run(self) -> None:
        """Serve until the run is over or a signal stops it."""
        asyncio.run(self._main())

    async def _main(self) -> None:
        loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self._signalled)
        self._sock = _udp_socket(self.endpoints.listen)
        self._agio = _udp_socket(None)
        loop.add_reader(self._sock.fileno(), self._drain)
        self._t0 = time.monotonic()
        print(f"vrsim serve aog-rc: modules {', '.join(self._describe())} listening on "
              f"{_where(self.endpoints.listen)}, reporting to {_where(self.endpoints.app)}"
              + (f"; AgIO to {_where(self.endpoints.agio)}, {self.field.ticks} ticks of "
                 f"{self.field.scenario.name}" if self.field else "")
              + f"; speed x{self.speed:g}; Ctrl-C stops", file=sys.stderr, flush=True)
        try:
            await asyncio.gather(self._ticking(), self._status())
        finally:
            loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._agio.close()
            self.write_status()

    def _signalled(self) -> None:
        self.ended = "signal"
        self._stop.set()

    def _describe(self) -> list[str]:
        return [f"{m.module_id} ({len(m.sensors)} sensor{'s' if len(m.sensors) > 1 else ''})"
                for m in self.modules.values()]


_AGIO_ENCODERS = {pgn.SteerData: pgn.encode_steer_data, pgn.MachineData: pgn.encode_machine_data,
                  pgn.SectionData: pgn.encode_section_data}


def _udp_socket(bind: tuple[str, int] | None) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
    if bind is not None:
        sock.bind(bind)
    sock.setblocking(False)
    return sock


def _where(addr: tuple[str, int]) -> str:
    return f"{addr[0]}:{addr[1]}"
