"""The AOG_RC PGNs as the rate module and AgIO side see them: decode what the app sends, encode what
they send back. Pure (bytes in, dataclasses out); nothing here touches a socket.

Layouts from SK21/AOG_RC at commit 6af548b905c4b52f4cad7d5bbb1c924c45ef662d (docs/aog_rc.md lists the
files): ``RateAppSource/RateController/PGNs/PGN32500.cs`` .. ``PGN32502.cs`` (app -> module),
``PGN32400.cs`` .. ``PGN32402.cs`` (module -> app), ``PGN254.cs``, ``PGN239.cs``, ``PGN229.cs`` (AgIO ->
app) and ``Classes/clsTools.cs`` (CRC, module/sensor byte). All integers little endian.

The module PGNs' check byte is the low byte of the sum of every byte before it; AgIO's (``0x80 0x81``
header) of the bytes from the third on. A packet that cannot be taken raises `Rejected` with one of
`REASONS` (the service counts them).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["AGIO_HEADER", "MAX_MODULES", "MAX_SENSORS", "REASONS", "MachineData", "ModuleInfo", "PidLog",
           "PidSettings", "RateCommand", "RateReport", "Rejected", "RelayCommand", "SectionData",
           "SteerData", "crc", "decode", "encode_machine_data", "encode_module_info", "encode_pid_log",
           "encode_rate_report", "encode_section_data", "encode_steer_data"]

MAX_MODULES = 8           # Props.MaxModules
MAX_SENSORS = 16          # Props.MaxSensorsPerModule (a nibble)
AGIO_HEADER = (0x80, 0x81)
PGN_RATE, PGN_RELAYS, PGN_PID = 32500, 32501, 32502
LENGTHS = {PGN_RATE: 14, PGN_RELAYS: 11, PGN_PID: 24}
TARGET_INVALID = 0xFFFFFF  # 2^24 - 1: the 24-bit field's all-ones, refused
#: Why a packet was dropped (the counters' names).
REASONS = ("short", "length", "crc", "unknown_pgn", "module_id", "sensor_id", "target", "pwm_settings",
           "rate_limited")


class Rejected(ValueError):
    """A packet dropped, with its `reason` (one of `REASONS`)."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def crc(data: bytes | bytearray, start: int = 0) -> int:
    """Low byte of the sum of ``data[start:]`` (``clsTools.CRC``)."""
    return sum(data[start:]) & 0xFF


@dataclass(frozen=True)
class RateCommand:
    """PGN 32500, the rate settings of one sensor (product).

    ``target_upm``: units per minute (the wire has 1000 x); ``meter_cal``: flow-meter pulses per unit
    (1000 x); ``control_type`` 0-7 (0 valve, 1 combo close, 2 motor, 3 motor weights, 4 fan, 5 combo
    close timed); the command byte's flags; ``manual_pwm``: signed PWM used when auto is off."""

    module: int
    sensor: int
    target_upm: float
    meter_cal: float
    control_type: int
    reset_quantity: bool
    master_on: bool
    pid_logging: bool
    auto_on: bool
    calibration: bool
    manual_pwm: int


@dataclass(frozen=True)
class RelayCommand:
    """PGN 32501, a module's relays: bit i of each 16-bit mask is relay i."""

    module: int
    relays: int
    power: int
    inverted: int
    flow_master: int   # 0-15, 255 disabled

    def any_section_on(self) -> bool:
        """The firmware's ``AnySectionOn``: a relay on (after inversion) that is not a power relay."""
        return ((self.relays ^ self.inverted) & ~self.power & 0xFFFF) != 0


@dataclass(frozen=True)
class PidSettings:
    """PGN 32502 as the firmware decodes it (``Receive.ino``): PWM limits 0-255 from percents, Kp and Ki
    the byte / 100, dead band a fraction (byte / 1000), brake point and slow adjust in %, slew in PWM
    per loop, max integral in PWM per loop (byte / 10), PID period ms, pulse limits Hz."""

    module: int = 0
    sensor: int = 0
    max_pwm: int = 255
    min_pwm: int = 5
    kp: float = 0.45
    ki: float = 0.70
    deadband: float = 0.015
    brake_point_pct: int = 35
    slow_adjust_pct: int = 60
    slew_rate: int = 25
    max_integral: float = 25.0
    timed_min_start: float = 0.5
    timed_adjust_ms: int = 80
    timed_pause_ms: int = 400
    pid_time_ms: int = 150
    pulse_min_hz: float = 1.0
    pulse_max_hz: float = 1500.0
    sample_window_cs: int = 40


@dataclass(frozen=True)
class RateReport:
    """PGN 32400, one sensor's report: applied units/min, accumulated units, PWM, sensor connected,
    bin empty, flow-meter Hz."""

    module: int
    sensor: int
    applied_upm: float
    quantity: float
    pwm: int
    connected: bool
    bin_empty: bool
    hz: float


@dataclass(frozen=True)
class ModuleInfo:
    """PGN 32401, a module's report (raw module ID in byte 2)."""

    module: int
    pressure: int = 0
    wheel_speed_kmh: float = 0.0
    wheel_counts: int = 0
    ino_type: int = 1
    ino_id: int = 15086
    status: int = 0b0011_0000   # ethernet connected, good pins


@dataclass(frozen=True)
class PidLog:
    """PGN 32402, one PID sample."""

    module: int
    sensor: int
    millis: int
    target_upm: float
    applied_upm: float
    error_upm: float
    integral: float
    change: float
    pwm: float
    samples: int
    ino_id: int = 15086


@dataclass(frozen=True)
class SteerData:
    """AgIO PGN 254: speed km/h and the sections 1-16 as relay bytes."""

    speed_kmh: float
    relays: int
    status: int = 0
    steer_angle: int = 0


@dataclass(frozen=True)
class MachineData:
    """AgIO PGN 239: u-turn, speed, hydraulic lift, tram, geo stop and the relay bytes."""

    speed_kmh: float
    relays: int
    uturn: int = 0
    hyd_lift: int = 0
    tram: int = 0
    geo_stop: int = 0


@dataclass(frozen=True)
class SectionData:
    """AgIO PGN 229: 64 sections (bit i of ``sections``) and the boom ends' speeds, m/s."""

    sections: int
    left_speed_m_s: float
    right_speed_m_s: float


# -- decoding what the app sends ------------------------------------------------------------------------

def decode(data: bytes):
    """The message in `data` (a module PGN the app sends: `RateCommand`, `RelayCommand` or
    `PidSettings`); `Rejected` otherwise."""
    if len(data) < 3:
        raise Rejected("short", f"{len(data)} bytes")
    pgn = data[0] | data[1] << 8
    length = LENGTHS.get(pgn)
    if length is None:
        raise Rejected("unknown_pgn", str(pgn))
    if len(data) != length:
        raise Rejected("length", f"PGN {pgn}: {len(data)} bytes, expected {length}")
    if crc(data[:-1]) != data[-1]:
        raise Rejected("crc", f"PGN {pgn}")
    module, sensor = data[2] >> 4, data[2] & 0x0F
    if module >= MAX_MODULES:
        raise Rejected("module_id", str(module))
    return _DECODERS[pgn](data, module, sensor)


def _u24(data: bytes, at: int) -> int:
    return data[at] | data[at + 1] << 8 | data[at + 2] << 16


def _rate(data: bytes, module: int, sensor: int) -> RateCommand:
    target = _u24(data, 3)
    if target == TARGET_INVALID:
        raise Rejected("target", "2^24-1")
    cmd = data[9]
    manual = int.from_bytes(data[10:12], "little", signed=True)
    return RateCommand(module, sensor, target / 1000.0, _u24(data, 6) / 1000.0, (cmd >> 1) & 0b111,
                       bool(cmd & 1), bool(cmd & 16), bool(cmd & 32), bool(cmd & 64), bool(cmd & 128), manual)


def _relays(data: bytes, module: int, sensor: int) -> RelayCommand:
    return RelayCommand(module, data[3] | data[4] << 8, data[5] | data[6] << 8, data[7] | data[8] << 8,
                        data[9])


def _pid(data: bytes, module: int, sensor: int) -> PidSettings:
    max_pct, min_pct = data[3], data[4]
    if max_pct == 0 or max_pct > 100 or min_pct > max_pct:
        raise Rejected("pwm_settings", f"max {max_pct} %, min {min_pct} %")
    min_hz_x10, max_hz = data[19], data[20] | data[21] << 8
    return PidSettings(
        module, sensor, max_pwm=int(255 * max_pct / 100), min_pwm=int(255 * min_pct / 100),
        kp=data[5] / 100.0, ki=data[6] / 100.0, deadband=data[7] / 1000.0, brake_point_pct=data[8],
        slow_adjust_pct=data[9], slew_rate=data[10], max_integral=data[11] / 10.0,
        timed_min_start=data[13] / 100.0, timed_adjust_ms=data[14] | data[15] << 8,
        timed_pause_ms=data[16] | data[17] << 8, pid_time_ms=data[18],
        pulse_min_hz=min_hz_x10 / 10.0 if min_hz_x10 else PidSettings.pulse_min_hz,
        pulse_max_hz=float(max_hz) if max_hz else PidSettings.pulse_max_hz,
        sample_window_cs=min(max(data[22], 5), 200))


_DECODERS = {PGN_RATE: _rate, PGN_RELAYS: _relays, PGN_PID: _pid}


# -- encoding what the module and AgIO send --------------------------------------------------------------

def _clip_u(value: float, bits: int) -> int:
    return min(max(int(value), 0), (1 << bits) - 1)


def _module_packet(pgn: int, body: bytes) -> bytes:
    data = bytes((pgn & 0xFF, pgn >> 8)) + body
    return data + bytes((crc(data),))


def encode_rate_report(r: RateReport) -> bytes:
    """PGN 32400, 15 bytes."""
    status = (1 if r.connected else 0) | (2 if r.bin_empty else 0)
    pwm = max(min(int(r.pwm), 32767), -32768)
    body = (bytes((r.module << 4 | r.sensor,)) + _clip_u(r.applied_upm * 1000, 24).to_bytes(3, "little")
            + _clip_u(r.quantity * 10, 24).to_bytes(3, "little") + pwm.to_bytes(2, "little", signed=True)
            + bytes((status,)) + _clip_u(r.hz * 10, 16).to_bytes(2, "little"))
    return _module_packet(32400, body)


def encode_module_info(m: ModuleInfo) -> bytes:
    """PGN 32401, 15 bytes."""
    body = (bytes((m.module,)) + _clip_u(m.pressure, 16).to_bytes(2, "little")
            + _clip_u(m.wheel_speed_kmh * 10, 16).to_bytes(2, "little")
            + _clip_u(m.wheel_counts, 24).to_bytes(3, "little") + bytes((m.ino_type,))
            + _clip_u(m.ino_id, 16).to_bytes(2, "little") + bytes((m.status,)))
    return _module_packet(32401, body)


def _s16(value: float) -> bytes:
    return max(min(int(value), 32767), -32768).to_bytes(2, "little", signed=True)


def encode_pid_log(p: PidLog) -> bytes:
    """PGN 32402, 26 bytes."""
    error = max(min(int(p.error_upm * 1000), (1 << 23) - 1), -(1 << 23)) & 0xFFFFFF
    body = (bytes((p.module << 4 | p.sensor,)) + (p.millis & 0xFFFFFFFF).to_bytes(4, "little")
            + _clip_u(p.target_upm * 1000, 24).to_bytes(3, "little")
            + _clip_u(p.applied_upm * 1000, 24).to_bytes(3, "little") + error.to_bytes(3, "little")
            + _s16(p.integral * 10) + _s16(p.change) + _s16(p.pwm) + bytes((min(p.samples, 255),))
            + _clip_u(p.ino_id, 16).to_bytes(2, "little"))
    return _module_packet(32402, body)


def _agio_packet(pgn: int, source: int, body: bytes) -> bytes:
    data = bytes((*AGIO_HEADER, source, pgn, len(body))) + body
    return data + bytes((crc(data, 2),))


def encode_steer_data(s: SteerData) -> bytes:
    """AgIO PGN 254 (source 0x7F), 14 bytes."""
    body = (_clip_u(s.speed_kmh * 10, 16).to_bytes(2, "little") + bytes((s.status,))
            + s.steer_angle.to_bytes(2, "little", signed=True)
            + bytes((0, s.relays & 0xFF, s.relays >> 8 & 0xFF)))
    return _agio_packet(254, 0x7F, body)


def encode_machine_data(m: MachineData) -> bytes:
    """AgIO PGN 239 (source 0x7E as PGN239.cs says), 14 bytes."""
    body = bytes((m.uturn, _clip_u(m.speed_kmh * 10, 8), m.hyd_lift, m.tram, m.geo_stop, 0,
                  m.relays & 0xFF, m.relays >> 8 & 0xFF))
    return _agio_packet(239, 0x7E, body)


def encode_section_data(s: SectionData) -> bytes:
    """AgIO PGN 229 (source 0x7F), 16 bytes."""
    body = (s.sections & (1 << 64) - 1).to_bytes(8, "little") + bytes(
        (_clip_u(s.left_speed_m_s * 10, 8), _clip_u(s.right_speed_m_s * 10, 8)))
    return _agio_packet(229, 0x7F, body)
