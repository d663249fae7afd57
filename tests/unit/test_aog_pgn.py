"""The AOG_RC PGNs against byte strings written by hand from the C# sources' layouts (SK21/AOG_RC at
6af548b: RateAppSource/RateController/PGNs/*.cs), both vrsim's module side (`services.aog.pgn`) and the
app's side (`services.aog.app_client`); and the firmware emulation's rules in process."""

import pytest

from vrsim.services.aog import app_client, pgn
from vrsim.services.aog.firmware import COMM_TIMEOUT_MS, LOOP_MS, MOTOR, DrivePlant, RateModule
from vrsim.services.sim.core import machine_plant
from vrsim.services.sim.machines import machine_for
from vrsim.services.sim.scenario import load
from vrsim.services.sim.world import build_world

pytestmark = pytest.mark.unit

# PGN 32500, module 1 sensor 2, 12.345 units/min, 10.5 pulses/unit, motor | MasterOn | AutoOn.
RATE_32500 = bytes([244, 126, 0x12, 0x39, 0x30, 0x00, 0x04, 0x29, 0x00, 0x54, 0, 0, 0, 110])
# PGN 32502, module 1 sensor 0, the app's defaults (Props.cs): max 100 %, min 2 %, Kp 45, Ki 70, ...
PID_32502 = bytes([246, 126, 0x10, 100, 2, 45, 70, 15, 35, 60, 25, 250, 0, 50, 80, 0, 0x90, 0x01, 150, 10,
                   0xDC, 0x05, 40, 154])
# PGN 32501, module 3: relays 0-3 and 9 on, relay 9 a power relay, none inverted, flow master off.
RELAYS_32501 = bytes([245, 126, 0x30, 0x0F, 0x02, 0x00, 0x02, 0x00, 0x00, 255,
                      (245 + 126 + 0x30 + 0x0F + 0x02 + 0x02 + 255) & 0xFF])
# PGN 32400, module 0 sensor 1: 40.406 units/min, 4.8 units, PWM -8, connected, 6.7 Hz.
REPORT_32400 = bytes([144, 126, 0x01, 0xD6, 0x9D, 0x00, 48, 0, 0, 0xF8, 0xFF, 1, 67, 0, 237])
# PGN 32402, module 0 sensor 1 at 1000 ms: target 40, applied 10, error 30, integral 12.3, change -5,
# PWM 82, 9 samples, InoID 15086.
LOG_32402 = bytes([146, 126, 0x01, 0xE8, 0x03, 0, 0, 0x40, 0x9C, 0, 0x10, 0x27, 0, 0x30, 0x75, 0, 0x7B, 0,
                   0xFB, 0xFF, 0x52, 0, 9, 0xEE, 0x3A, 172])
# AgIO 254: 8.5 km/h, sections 1-4 on.
STEER_254 = bytes([0x80, 0x81, 0x7F, 0xFE, 8, 85, 0, 0, 0, 0, 0, 0x0F, 0x00, 233])
# AgIO 229: sections 1-4 and 64 on, boom ends at 2.5 and 2.7 m/s.
SECTIONS_229 = bytes([0x80, 0x81, 0x7F, 229, 10, 0x0F, 0, 0, 0, 0, 0, 0, 0x80, 25, 27, 49])


def test_rate_command_decodes_as_the_firmware_reads_it_and_the_app_builds_it():
    msg = pgn.decode(RATE_32500)
    assert (msg.module, msg.sensor, msg.control_type) == (1, 2, MOTOR)
    assert msg.target_upm == pytest.approx(12.345) and msg.meter_cal == pytest.approx(10.5)
    assert msg.master_on and msg.auto_on and not msg.pid_logging and not msg.calibration
    assert app_client.rate_settings(1, 2, 12.345, 10.5, control_type=2) == RATE_32500


def test_pid_settings_decode_with_the_firmware_scaling_and_the_app_builds_them():
    s = pgn.decode(PID_32502)
    assert (s.module, s.sensor, s.max_pwm, s.min_pwm) == (1, 0, 255, 5)
    assert (s.kp, s.ki, s.deadband, s.brake_point_pct, s.slow_adjust_pct) == (0.45, 0.70, 0.015, 35, 60)
    assert (s.slew_rate, s.max_integral, s.pid_time_ms, s.timed_pause_ms) == (25, 25.0, 150, 400)
    assert (s.pulse_min_hz, s.pulse_max_hz, s.sample_window_cs) == (1.0, 1500.0, 40)
    assert app_client.pid_settings(1, 0) == PID_32502


def test_relays_decode_and_any_section_on_ignores_power_relays():
    r = pgn.decode(RELAYS_32501)
    assert (r.module, r.relays, r.power, r.flow_master) == (3, 0x020F, 0x0200, 255)
    assert r.any_section_on()
    assert app_client.relay_settings(3, 0x020F, power=0x0200) == RELAYS_32501
    only_power = pgn.decode(app_client.relay_settings(3, 0x0200, power=0x0200))
    assert not only_power.any_section_on()


def test_module_reports_encode_to_the_hand_written_bytes_and_the_app_parses_them():
    report = pgn.RateReport(0, 1, 40.406, 4.8, -8, True, False, 6.7)
    assert pgn.encode_rate_report(report) == REPORT_32400
    parsed = app_client.parse_module(REPORT_32400)
    assert parsed["upm"] == pytest.approx(40.406) and parsed["pwm"] == -8 and parsed["connected"]
    log = pgn.PidLog(0, 1, 1000, 40.0, 10.0, 30.0, 12.3, -5, 82, 9)
    assert pgn.encode_pid_log(log) == LOG_32402
    parsed = app_client.parse_module(LOG_32402)
    assert (parsed["millis"], parsed["error"], parsed["integral"], parsed["change"]) == (1000, 30.0, 12.3, -5)
    info = pgn.encode_module_info(pgn.ModuleInfo(2))
    assert len(info) == 15 and info[:3] == bytes([145, 126, 2])
    assert app_client.parse_module(info)["module"] == 2


def test_agio_messages_encode_to_the_hand_written_bytes():
    assert pgn.encode_steer_data(pgn.SteerData(8.5, 0x000F)) == STEER_254
    assert pgn.encode_section_data(pgn.SectionData(0x0F | 1 << 63, 2.5, 2.7)) == SECTIONS_229
    machine = pgn.encode_machine_data(pgn.MachineData(8.5, 0x000F))
    assert len(machine) == 14 and machine[3] == 239 and machine[6] == 85 and machine[11] == 0x0F


def _bad(data: bytes) -> bytes:
    return data[:-1] + bytes(((data[-1] + 1) & 0xFF,))


@pytest.mark.parametrize("data, reason", [
    (_bad(RATE_32500), "crc"),
    (RATE_32500[:-2] + RATE_32500[-1:], "length"),
    (RATE_32500 + b"\x00", "length"),
    (b"\xF4", "short"),
    (bytes([0x10, 0x27, 0, 0]), "unknown_pgn"),
    (app_client.rate_settings(9, 0, 1.0, 1.0), "module_id"),
    (app_client.rate_settings(0, 0, (2 ** 24 - 1) / 1000.0, 1.0), "target"),
    (app_client.pid_settings(0, 0, max_pwm_pct=0, min_pwm_pct=0), "pwm_settings"),
    (app_client.pid_settings(0, 0, max_pwm_pct=20, min_pwm_pct=30), "pwm_settings"),
])
def test_bad_packets_are_rejected_with_their_reason(data, reason):
    with pytest.raises(pgn.Rejected) as exc:
        pgn.decode(data)
    assert exc.value.reason == reason and reason in pgn.REASONS


@pytest.fixture(scope="module")
def plant():
    sc = load(None, [])
    world = build_world(sc)
    machine = machine_for(world.scenario.implement, world.field.polygon)
    return machine_plant(world.scenario, world.grid, machine), float(machine.configured_kg(1.0, sc.product))


def _module(plant) -> RateModule:
    params, units_per_rev = plant
    module = RateModule(0, [DrivePlant(params, units_per_rev)])
    module.apply(pgn.decode(app_client.relay_settings(0, 0xFF)), 0)
    return module


def test_the_pid_settles_within_the_dead_band_and_stops_4_s_after_the_last_command(plant):
    module = _module(plant)
    command = pgn.decode(app_client.rate_settings(0, 0, 40.0, 10.0, control_type=2))
    for k in range(400):   # 20 s, a command a second
        if k % 20 == 0:
            module.apply(command, k * LOOP_MS)
        module.tick(k * LOOP_MS)
    ch = module.sensors[0]
    assert ch.connected and abs(ch.meter.upm - 40.0) <= 40.0 * ch.settings.deadband + 0.2
    last = 399 * LOOP_MS
    module.apply(command, last)
    k = 400
    while (k * LOOP_MS) - last < COMM_TIMEOUT_MS:
        module.tick(k * LOOP_MS)
        assert ch.connected and ch.output_pwm > 0
        k += 1
    module.tick(k * LOOP_MS)
    assert not ch.connected and ch.output_pwm == 0.0 and ch.pwm == 0.0


def test_sections_off_stop_the_motor_and_the_count(plant):
    module = _module(plant)
    command = pgn.decode(app_client.rate_settings(0, 0, 40.0, 10.0, control_type=2))
    for k in range(200):
        module.apply(command, k * LOOP_MS)
        module.tick(k * LOOP_MS)
    ch = module.sensors[0]
    assert ch.meter.upm > 30.0
    module.apply(pgn.decode(app_client.relay_settings(0, 0)), 200 * LOOP_MS)
    for k in range(200, 300):
        module.apply(command, k * LOOP_MS)
        module.tick(k * LOOP_MS)
    counted = ch.meter.total_pulses
    module.tick(300 * LOOP_MS)
    assert ch.meter.upm == 0.0 and ch.output_pwm == 0.0 and ch.plant.flow_upm < 0.5
    assert ch.meter.total_pulses == counted
