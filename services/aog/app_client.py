"""The Rate Controller app's side of AOG_RC's UDP protocol, for tests and `vrsim aog`.

Written from the app's C# sources (SK21/AOG_RC at commit 6af548b905c4b52f4cad7d5bbb1c924c45ef662d,
``RateAppSource/RateController/``), on its own: it imports nothing of vrsim's module side
(`services.aog.pgn` and the rest), so a test of one against the other checks both against the layouts.

* what the app sends the modules, to UDP port 28888 (``Classes/Core.cs``: ``UDPmodules`` sends to 28888,
  receives on 29999): ``PGNs/PGN32500.cs`` (rate settings), ``PGN32501.cs`` (relays), ``PGN32502.cs``
  (PID settings);
* what it reads from them on 29999: ``PGN32400.cs``, ``PGN32401.cs``, ``PGN32402.cs``;
* what it reads from AgIO on 17777 (``UDPaog``): ``PGN254.cs`` (speed smoothed 0.75/0.25, relay bytes),
  ``PGN239.cs``, ``PGN229.cs`` (64 sections, the boom ends' speeds);
* how it turns a rate per area into units per minute (``Classes/clsProduct.cs`` ``TargetUPM``,
  ``clsSections.cs``: hectares per minute = width of the sections on, m, x km/h / 600).
"""

from __future__ import annotations

import select
import socket
import time
from collections import deque
from dataclasses import dataclass

__all__ = ["AppClient", "AppProduct", "CONNECTED_S", "parse_module", "pid_settings", "rate_settings",
           "relay_settings"]

CONNECTED_S = 4.0   # the app's "connected": a packet within 4 s (PGN254.Connected, PGN229.Connected)


def _sum_byte(buf, start: int = 0) -> int:
    """``clsTools.CRC``: the low byte of the bytes' sum from `start`."""
    total = 0
    for b in buf[start:]:
        total += b
    return total & 0xFF


def _with_check(buf: bytearray) -> bytes:
    buf[-1] = _sum_byte(buf[:-1])
    return bytes(buf)


def _good(buf: bytes, start: int = 0) -> bool:
    """``clsTools.GoodCRC``."""
    return len(buf) > start and _sum_byte(buf[:-1], start) == buf[-1]


def _put24(buf: bytearray, at: int, value: int) -> None:
    buf[at], buf[at + 1], buf[at + 2] = value & 0xFF, value >> 8 & 0xFF, value >> 16 & 0xFF


def rate_settings(module: int, sensor: int, target_upm: float, meter_cal: float, control_type: int = 0,
                  master_on: bool = True, auto_on: bool = True, pid_logging: bool = False,
                  calibration: bool = False, reset_quantity: bool = False, manual_pwm: int = 0) -> bytes:
    """PGN 32500 as ``PGN32500.Send`` builds it (14 bytes)."""
    buf = bytearray(14)
    buf[0], buf[1], buf[2] = 244, 126, (module << 4 | sensor & 0x0F) & 0xFF
    _put24(buf, 3, int(target_upm * 1000.0))
    _put24(buf, 6, int(meter_cal * 1000.0))
    command = {0: 0, 1: 2, 2: 4, 3: 6, 4: 8, 5: 10}[control_type]
    command |= (1 if reset_quantity else 0) | (16 if master_on else 0) | (32 if pid_logging else 0)
    command |= (64 if auto_on else 0) | (128 if calibration else 0)
    buf[9] = command
    buf[10], buf[11] = manual_pwm & 0xFF, manual_pwm >> 8 & 0xFF
    return _with_check(buf)


def relay_settings(module: int, relays: int, power: int = 0, inverted: int = 0,
                   flow_master: int = 255) -> bytes:
    """PGN 32501 as ``PGN32501.Send`` builds it (11 bytes)."""
    buf = bytearray(11)
    buf[0], buf[1], buf[2] = 245, 126, (module << 4) & 0xFF
    buf[3], buf[4] = relays & 0xFF, relays >> 8 & 0xFF
    buf[5], buf[6] = power & 0xFF, power >> 8 & 0xFF
    buf[7], buf[8] = inverted & 0xFF, inverted >> 8 & 0xFF
    buf[9] = flow_master
    return _with_check(buf)


def pid_settings(module: int, sensor: int, max_pwm_pct: int = 100, min_pwm_pct: int = 2, kp: int = 45,
                 ki: int = 70, deadband: int = 15, brake_point: int = 35, slow_adjust: int = 60,
                 slew_rate: int = 25, max_integral: int = 250, timed_min_start: int = 50,
                 timed_adjust_ms: int = 80, timed_pause_ms: int = 400, pid_time_ms: int = 150,
                 pulse_min_hz_x10: int = 10, pulse_max_hz: int = 1500, sample_window_cs: int = 40) -> bytes:
    """PGN 32502 as ``PGN32502.Send`` builds it from the sensor's settings (24 bytes; the app's units:
    PWM in %, Kp and Ki sliders 0-100, dead band in 0.1 %, max integral x 10; defaults Props.cs')."""
    buf = bytearray(24)
    buf[0], buf[1], buf[2] = 246, 126, (module << 4 | sensor & 0x0F) & 0xFF
    for at, value in enumerate((max_pwm_pct, min_pwm_pct, kp, ki, deadband, brake_point, slow_adjust,
                                slew_rate, max_integral), start=3):
        buf[at] = value
    buf[13] = timed_min_start
    buf[14], buf[15] = timed_adjust_ms & 0xFF, timed_adjust_ms >> 8 & 0xFF
    buf[16], buf[17] = timed_pause_ms & 0xFF, timed_pause_ms >> 8 & 0xFF
    buf[18], buf[19] = pid_time_ms, pulse_min_hz_x10
    buf[20], buf[21] = pulse_max_hz & 0xFF, pulse_max_hz >> 8 & 0xFF
    buf[22] = sample_window_cs
    return _with_check(buf)


def _s16(lo: int, hi: int) -> int:
    v = lo | hi << 8
    return v - 0x10000 if v & 0x8000 else v


def parse_module(data: bytes) -> dict | None:
    """A module's packet as the app parses it (``UDPComm.HandleData`` -> ``PGN32400/32401/32402
    .ParseByteData``): a dict with ``pgn``; None where the app would ignore it."""
    if len(data) < 2:
        return None
    pgn = data[1] << 8 | data[0]
    if pgn == 32400 and len(data) >= 15 and _good(data):
        return {"pgn": 32400, "module": data[2] >> 4, "sensor": data[2] & 0x0F,
                "upm": (data[5] << 16 | data[4] << 8 | data[3]) / 1000.0,
                "quantity": (data[8] << 16 | data[7] << 8 | data[6]) / 10.0, "pwm": _s16(data[9], data[10]),
                "connected": bool(data[11] & 1), "bin_empty": bool(data[11] & 2),
                "hz": (data[12] | data[13] << 8) / 10.0}
    if pgn == 32401 and len(data) >= 15 and _good(data) and data[2] < 8:
        return {"pgn": 32401, "module": data[2], "pressure": data[3] | data[4] << 8,
                "wheel_speed": (data[5] | data[6] << 8) / 10.0, "ino_type": data[10],
                "ino_id": data[11] | data[12] << 8, "status": data[13]}
    if pgn == 32402 and len(data) >= 26 and _good(data):
        error = data[13] | data[14] << 8 | data[15] << 16
        if error & 0x800000:
            error -= 1 << 24
        return {"pgn": 32402, "module": data[2] >> 4, "sensor": data[2] & 0x0F,
                "millis": int.from_bytes(data[3:7], "little"),
                "target": (data[7] | data[8] << 8 | data[9] << 16) / 1000.0,
                "applied": (data[10] | data[11] << 8 | data[12] << 16) / 1000.0, "error": error / 1000.0,
                "integral": _s16(data[16], data[17]) / 10.0, "change": _s16(data[18], data[19]),
                "pwm": _s16(data[20], data[21]), "samples": data[22]}
    return None


class AppClient:
    """The app's two UDP links: to and from the modules, and from AgIO.

    Parameters
    ----------
    modules : (host, port)
        Where the modules listen (the app sends there: 28888).
    listen : (host, port)
        Where the app receives the modules' reports (29999).
    agio_listen : (host, port), optional
        Where the app receives AgIO's PGNs (17777); None: no AgIO link.
    """

    def __init__(self, modules=("127.0.0.1", 28888), listen=("127.0.0.1", 29999), agio_listen=None):
        self.modules = modules
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(listen)
        self.agio = None
        if agio_listen is not None:
            self.agio = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.agio.bind(agio_listen)
        self.rates: dict[tuple[int, int], dict] = {}    # latest 32400 per (module, sensor)
        self.infos: dict[int, dict] = {}                # latest 32401 per module
        self.pid_log: deque = deque(maxlen=10000)       # 32402 samples
        self.received = 0
        self.speed_kmh = 0.0
        self.relay_lo = self.relay_hi = 0
        self.sections = 0
        self.boom_speeds_m_s = (0.0, 0.0)
        self.steer_at = self.sections_at = -1e9
        self.agio_packets = 0

    def close(self) -> None:
        self.sock.close()
        if self.agio is not None:
            self.agio.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- sending -------------------------------------------------------------------------------------------
    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.modules)

    def send_rate(self, module: int, sensor: int, target_upm: float, meter_cal: float, **flags) -> None:
        """PGN 32500 (`rate_settings`)."""
        self.send(rate_settings(module, sensor, target_upm, meter_cal, **flags))

    def send_relays(self, module: int, relays: int, **kw) -> None:
        """PGN 32501 (`relay_settings`)."""
        self.send(relay_settings(module, relays, **kw))

    def send_pid(self, module: int, sensor: int, **settings) -> None:
        """PGN 32502 (`pid_settings`)."""
        self.send(pid_settings(module, sensor, **settings))

    # -- receiving -----------------------------------------------------------------------------------------
    def poll(self, timeout_s: float = 0.0) -> list[dict]:
        """Read what has arrived within `timeout_s`; returns the module packets parsed (and keeps them)."""
        socks = [s for s in (self.sock, self.agio) if s is not None]
        got = []
        deadline = time.monotonic() + timeout_s
        while True:
            ready, _, _ = select.select(socks, [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                return got
            for s in ready:
                data = s.recv(2048)
                if s is self.agio:
                    self._agio_packet(data)
                    continue
                msg = parse_module(data)
                if msg is None:
                    continue
                msg["at"] = time.monotonic()   # when it was read
                self.received += 1
                got.append(msg)
                if msg["pgn"] == 32400:
                    self.rates[(msg["module"], msg["sensor"])] = msg
                elif msg["pgn"] == 32401:
                    self.infos[msg["module"]] = msg
                else:
                    self.pid_log.append(msg)
            if time.monotonic() >= deadline:
                return got

    def wait_for(self, condition, timeout_s: float, step_s: float = 0.05) -> bool:
        """Poll until ``condition(self)`` holds or `timeout_s` passes."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.poll(step_s)
            if condition(self):
                return True
        return False

    def _agio_packet(self, data: bytes) -> None:
        """AgIO's 254/239/229 as ``PGN254/239/229.ParseByteData`` read them."""
        if len(data) <= 5 or data[0] != 0x80 or data[1] != 0x81 or len(data) != data[4] + 6 \
                or not _good(data, 2):
            return
        self.agio_packets += 1
        now = time.monotonic()
        if data[3] == 254:
            self.speed_kmh = self.speed_kmh * 0.75 + ((data[6] << 8 | data[5]) / 10.0) * 0.25
            self.relay_lo, self.relay_hi = data[11], data[12]
            self.steer_at = now
        elif data[3] == 229:
            self.sections = int.from_bytes(data[5:13], "little")
            self.boom_speeds_m_s = (data[13] / 10.0, data[14] / 10.0)
            self.sections_at = now

    def section_on(self, i: int) -> bool:
        """``PGN229.SectionIsOn``: from 229 while it is connected, else 254's relay bytes."""
        now = time.monotonic()
        if now - self.sections_at < CONNECTED_S:
            return bool(self.sections >> i & 1)
        if i < 16:
            return bool((self.relay_hi << 8 | self.relay_lo) >> i & 1)
        return False

    def speed(self) -> float:
        """``PGN254.Speed_KMH``: the smoothed speed while connected, else 0."""
        return self.speed_kmh if time.monotonic() - self.steer_at < CONNECTED_S else 0.0


@dataclass
class AppProduct:
    """One product as the app runs it: a rate per hectare over sections of given widths, its module
    and sensor, meter calibration (pulses per unit) and control type."""

    module: int
    sensor: int
    rate_per_ha: float
    section_widths_m: tuple
    meter_cal: float
    control_type: int = 0

    def working_width_m(self, client: AppClient) -> float:
        """``clsSections.WorkingWidth``: the widths of the sections on (master on)."""
        return sum(w for i, w in enumerate(self.section_widths_m) if client.section_on(i))

    def target_upm(self, client: AppClient) -> float:
        """``clsProduct.TargetUPM`` for a product in units per hectare, section controlled: rate x
        hectares per minute (width m x km/h / 600)."""
        return self.rate_per_ha * self.working_width_m(client) * client.speed() / 600.0

    def relays(self, client: AppClient) -> int:
        """Relay i follows section i (the app's default relay list)."""
        return sum(1 << i for i in range(min(len(self.section_widths_m), 16)) if client.section_on(i))

    def send(self, client: AppClient, **flags) -> float:
        """Send this product's 32501 and 32500 now; returns the target sent (units/min)."""
        target = self.target_upm(client)
        client.send_relays(self.module, self.relays(client))
        client.send_rate(self.module, self.sensor, target, self.meter_cal, control_type=self.control_type,
                         **flags)
        return target
