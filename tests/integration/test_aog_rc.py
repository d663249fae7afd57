"""`vrsim serve aog-rc` as a real process on 127.0.0.1, driven over real UDP by the app's side
(`services.aog.app_client`, written from the Rate Controller's C# sources apart from the server's codec).

One server of the modules alone (module 0 with two sensors, module 1 with one) serves the step, the 4 s
rule, the relays and the bad packets, at 4 x real time; a field run of a small scenario at 10 x gives the
run's usual outputs. Deadlines are generous (the machine may run 2-5 x slower); nothing asserts wall time.
"""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from vrsim.services.aog.app_client import AppClient, AppProduct, pid_settings, rate_settings, relay_settings

pytestmark = pytest.mark.integration

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SPEED = 4.0
METER_CAL = 10.0
DEADLINE_S = 60.0


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(args: list[str], out_dir: str) -> tuple[subprocess.Popen, tuple, tuple, tuple]:
    modules, app, agio = (("127.0.0.1", _free_port()) for _ in range(3))
    argv = [sys.executable, "-P", "-m", "vrsim.services.cli", "serve", "aog-rc", *args,
            "--listen", f"127.0.0.1:{modules[1]}", "--app", f"127.0.0.1:{app[1]}",
            "--agio", f"127.0.0.1:{agio[1]}", "--out", out_dir]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, modules, app, agio


def _stop(proc: subprocess.Popen) -> tuple[str, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=120)


def _status(out_dir: str) -> dict:
    with open(os.path.join(out_dir, "status.json")) as fh:
        return json.load(fh)


def _sensor(status: dict, module: int, sensor: int) -> dict:
    return next(s for s in status["sensors"] if (s["module"], s["sensor"]) == (module, sensor))


@pytest.fixture(scope="module")
def modules_only(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("aog-modules"))
    proc, modules, app, _ = _serve(["--no-field", "--modules", "0:2,1:1", "--speed", str(SPEED)], out)
    client = AppClient(modules, app)
    try:
        assert client.wait_for(lambda c: 32401 in {m["pgn"] for m in c.poll(0.0)} or c.infos, DEADLINE_S), \
            proc.stderr.read() if proc.poll() is not None else "no report from the modules"
        yield proc, client, out
    finally:
        client.close()
        _stop(proc)


def _hold(client: AppClient, seconds_sim: float, commands, until=None) -> bool:
    """Send `commands` (packets) 5 times a simulated second for `seconds_sim` simulated seconds (or
    until ``until(client)``), reading the reports meanwhile."""
    deadline = time.monotonic() + max(seconds_sim / SPEED * 4.0, 10.0)
    end = time.monotonic() + seconds_sim / SPEED
    while time.monotonic() < (deadline if until else end):
        for packet in commands:
            client.send(packet)
        client.poll(0.2 / SPEED)
        if until is not None and until(client):
            return True
    return until is None


def _inprocess_step(target: float, control_type: int, seconds: float) -> list[tuple[int, float, float]]:
    """The same firmware on the same plant in process: (millis, target, applied) of each PID sample."""
    from vrsim.services.aog import pgn
    from vrsim.services.aog.firmware import LOOP_MS, DrivePlant, RateModule
    from vrsim.services.sim.core import machine_plant
    from vrsim.services.sim.machines import machine_for
    from vrsim.services.sim.scenario import load
    from vrsim.services.sim.world import build_world

    sc = load(None, [])
    world = build_world(sc)
    machine = machine_for(world.scenario.implement, world.field.polygon)
    module = RateModule(0, [DrivePlant(machine_plant(world.scenario, world.grid, machine),
                                       float(machine.configured_kg(1.0, sc.product)))])
    module.apply(pgn.decode(pid_settings(0, 0)), 0)
    module.apply(pgn.RelayCommand(0, 0xFFFF, 0, 0, 255), 0)
    command = pgn.decode(rate_settings(0, 0, target, METER_CAL, control_type=control_type, pid_logging=True))
    samples = []
    for k in range(int(seconds * 1000 / LOOP_MS)):
        if k % 4 == 0:
            module.apply(command, k * LOOP_MS)
        module.tick(k * LOOP_MS)
        samples += [(log.millis, log.target_upm, log.applied_upm) for log in module.pid_logs()]
    return samples


def _rise_ms(samples, target: float) -> float:
    start = next(m for m, t, _ in samples if t > 0)
    return next(m for m, t, a in samples if t > 0 and a >= 0.9 * target) - start


def test_a_target_step_settles_as_the_firmware_on_the_plant_predicts(modules_only):
    """Module 0 sensor 0, a valve, 0 -> 40 units/min: the rise to 90 % within 0.3 s (two PID periods)
    of the in-process run's, the settled rate within 2 % of the target and of the in-process run's."""
    _, client, _ = modules_only
    target = 40.0
    client.send(pid_settings(0, 0))
    relays = client.send_relays
    relays(0, 0xFFFF)
    command = rate_settings(0, 0, target, METER_CAL, control_type=0, pid_logging=True)
    _hold(client, 15.0, [command])
    served = [(s["millis"], s["target"], s["applied"]) for s in client.pid_log if s["module"] == 0
              and s["sensor"] == 0]
    local = _inprocess_step(target, 0, 15.0)
    assert served, "no PID samples (PGN 32402) from the module"
    assert abs(_rise_ms(served, target) - _rise_ms(local, target)) <= 300
    settled_served = [a for m, t, a in served if m >= served[-1][0] - 3000]
    settled_local = [a for m, t, a in local if m >= local[-1][0] - 3000]
    mean_served = sum(settled_served) / len(settled_served)
    mean_local = sum(settled_local) / len(settled_local)
    assert abs(mean_served - target) <= 0.02 * target
    assert abs(mean_served - mean_local) <= 0.02 * target
    report = client.rates[(0, 0)]
    assert report["connected"] and abs(report["upm"] - target) <= 0.02 * target
    assert report["hz"] == pytest.approx(report["upm"] * METER_CAL / 60.0, abs=0.15)


def test_b_no_command_for_4_s_stops_the_control(modules_only):
    """Module 0 sensor 1, a motor: commands stop, the module reports itself disconnected, PWM 0 and no
    flow; commands again, it runs again."""
    _, client, out = modules_only
    client.send_relays(0, 0xFFFF)
    command = rate_settings(0, 1, 30.0, METER_CAL, control_type=2)
    assert _hold(client, 30.0, [command], until=lambda c: c.rates.get((0, 1), {}).get("upm", 0) > 25.0)
    assert client.wait_for(lambda c: not c.rates[(0, 1)]["connected"] and c.rates[(0, 1)]["pwm"] == 0,
                           DEADLINE_S)
    assert client.wait_for(lambda c: c.rates[(0, 1)]["upm"] == 0.0, DEADLINE_S)
    status = _sensor(_status(out), 0, 1)
    assert not status["connected"] and status["flow_upm"] < 0.5
    assert _hold(client, 30.0, [command], until=lambda c: c.rates[(0, 1)]["upm"] > 25.0)


def test_c_section_relays_off_close_the_flow(modules_only):
    """Module 1, a motor: all relays off stops the PID, the motor and the count; on again, it flows."""
    _, client, out = modules_only
    command = rate_settings(1, 0, 30.0, METER_CAL, control_type=2)
    on = [command, relay_settings(1, 0x00FF)]
    assert _hold(client, 30.0, on, until=lambda c: c.rates.get((1, 0), {}).get("upm", 0) > 25.0)
    off = [command, relay_settings(1, 0)]
    assert _hold(client, 30.0, off,
                 until=lambda c: c.rates[(1, 0)]["upm"] == 0.0 and c.rates[(1, 0)]["pwm"] == 0)
    quantity = client.rates[(1, 0)]["quantity"]
    _hold(client, 2.0, off)
    assert client.rates[(1, 0)]["quantity"] == quantity
    assert client.wait_for(lambda c: _sensor(_status(out), 1, 0)["flow_upm"] < 0.5, DEADLINE_S)
    assert _hold(client, 30.0, on, until=lambda c: c.rates[(1, 0)]["upm"] > 25.0)


def test_d_bad_packets_are_dropped_and_counted(modules_only):
    proc, client, out = modules_only
    before = _status(out)["dropped"]
    good = rate_settings(0, 0, 40.0, METER_CAL)
    bad = {"crc": good[:-1] + bytes([(good[-1] + 1) & 0xFF]),
           "length": good + b"\x00",
           "short": b"\xF4",
           "unknown_pgn": bytes([0x10, 0x27, 0, 0, 0x37]),
           "module_id": rate_settings(9, 0, 1.0, METER_CAL),
           "sensor_id": rate_settings(0, 5, 1.0, METER_CAL),
           "not_ours": rate_settings(4, 0, 1.0, METER_CAL),
           "target": rate_settings(0, 0, (2 ** 24 - 1) / 1000.0, METER_CAL),
           "pwm_settings": pid_settings(0, 0, max_pwm_pct=0, min_pwm_pct=0)}
    for packet in bad.values():
        for _ in range(3):
            client.send(packet)

    def counted(c) -> bool:
        dropped = _status(out)["dropped"]
        return all(dropped[reason] - before[reason] == 3 for reason in bad)
    assert client.wait_for(counted, DEADLINE_S), _status(out)["dropped"]
    assert proc.poll() is None
    reports = client.received
    assert client.wait_for(lambda c: c.received > reports + 5, DEADLINE_S)


SMALL = """name = "aog_small"
seed = 3

[field]
rectangle = { width_m = 36.0, length_m = 60.0, lat = 48.2, lon = 11.6 }
headland_passes = 0

[map]
synthetic = "random_field"
cell_size_m = 2.0
params = { mean_kg_ha = 160.0, std_kg_ha = 30.0, correlation_length_m = 20.0 }

[implement]
width_m = 12.0
sections = 4
delivery_delay_s = 0.8
"""


def test_e_a_field_run_with_the_client_as_the_app_writes_the_usual_outputs(tmp_path):
    """The client reads AgIO's speed and sections and sends 160 kg/ha as the app computes it; the run
    ends at the end of the path with the report, the applied map and the aog-rc files."""
    scenario = tmp_path / "small.toml"
    scenario.write_text(SMALL)
    out = str(tmp_path / "out")
    proc, modules, app, agio = _serve([str(scenario), "--speed", "10"], out)
    product = AppProduct(0, 0, 160.0, (3.0, 3.0, 3.0, 3.0), METER_CAL)
    targets = []
    with AppClient(modules, app, agio) as client:
        client.send(pid_settings(0, 0))
        assert client.wait_for(lambda c: c.agio_packets > 0, 120.0), "no AgIO packet"
        while proc.poll() is None:
            targets.append(product.send(client))
            client.poll(0.02)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    assert "end of the path" in stderr
    for name in ("report.html", "map.png", "as_applied.tif", "summary.json", "timeseries.png",
                 "aog_rc.csv", "aog_rc.json", "aog_rc.png"):
        assert os.path.isfile(os.path.join(out, name)), name
    assert max(targets) > 0.5 * 160.0 * 12.0 * 8.0 / 600.0   # about 8 km/h over 12 m
    with open(os.path.join(out, "summary.json")) as fh:
        summary = json.load(fh)
    assert abs(summary["mass_balance_pct"]) < 15.0
    with open(os.path.join(out, "aog_rc.json")) as fh:
        counts = json.load(fh)
    assert counts["accepted"]["32500"] > 50 and counts["dropped_total"] == 0 and counts["sent"]["agio"] > 100
