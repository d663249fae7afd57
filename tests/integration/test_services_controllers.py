"""Controller kinds other than the PID through the services in lockstep: a Smith predictor with the
look-ahead auto-tune (metering a product whose flow varies revolution to revolution, 3 % off its
configured constant), and a user's controller class from a file, each give the same metrics as
`vrsim run` to 1e-9 relative (every service a separate process, on loopback). A user's file outside
the folders the controller service allows is refused."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import numpy as np
import pytest

from tests.conftest import ROOT, VRSIM
from tests.integration.test_services_support import (
    MONITOR_KEYS,
    ServeAll,
    assert_same_summary,
    write_field_files,
)

CONTROLLERS = {
    "smith": '[controller]\nkind = "smith"\nlook_ahead_s = "auto"\nlook_ahead_tune = 0.5\n'
             '[product]\nflow_cv_pct = 6.0\ncalibration_error_pct = 3.0\n',
    "user": '[controller]\nkind = "python"\nfile = "my_controller.py"\nclass = "MyController"\n'
            'params = { kp_a_per_rpm = 0.002, ki_a_per_rpm_s = 0.01 }\n',
}

# A drive per section, the shaft's range just above the straight passes' need: single drives sit on it.
DRIVES = '[implement]\nkind = "section_drives"\nsections = 4\nshaft_rpm_max = 92.0\n'
# A PWM boom sprayer (a flow loop per section) of a liquid: the map's 150-250 kg/ha are L/ha at 1.0 kg/L.
SPRAYER = '[implement]\nkind = "sprayer"\nnozzle = "06"\ncontrol = "pwm"\n'
# A twin-disc spinner, 14 m driving width (24 m spread) on the 36 m wide field: its last pass overlaps the
# one before, where coverage control shortens a side in 4 steps over ground already treated.
SPINNER = ('[implement]\nkind = "spinner"\nsections = 2\nspread_width_m = 24.0\nthrow_distance_m = 4.0\n'
           'side_steps = 4\nsection_control = "coverage"\n')


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """The services' small field and map, one scenario per controller, and the example user class."""
    path = str(tmp_path_factory.mktemp("svc-ctl"))
    files = write_field_files(path)
    with open(files["scenario"]) as fh:
        base = fh.read()
    for name, table in CONTROLLERS.items():
        with open(os.path.join(path, f"{name}.toml"), "w") as fh:
            fh.write(base.replace('name = "svc-small"', f'name = "svc-{name}"') + table)
    with open(os.path.join(path, "drives.toml"), "w") as fh:
        fh.write(base.replace('name = "svc-small"', 'name = "svc-drives"').replace("[implement]\n", DRIVES))
    with open(os.path.join(path, "sprayer.toml"), "w") as fh:
        fh.write(base.replace('name = "svc-small"', 'name = "svc-sprayer"').replace("[implement]\n", SPRAYER)
                 + '[product]\nform = "liquid"\ndensity_kg_l = 1.0\n')
    with open(os.path.join(path, "spinner.toml"), "w") as fh:
        fh.write(base.replace('name = "svc-small"', 'name = "svc-spinner"').replace("[implement]\n", SPINNER)
                 .replace("width_m = 12.0", "width_m = 14.0"))
    shutil.copy(os.path.join(ROOT, "scenarios", "my_controller.py"), path)
    return path


@pytest.fixture(scope="module")
def net(folder):
    server = ServeAll(folder, "--allow-user-code", folder)
    try:
        server.wait_ready()
        yield server
    finally:
        assert server.stop() == 0, server.output()


def start(net, folder, name):
    path = os.path.join(folder, f"{name}.toml")
    with open(path, "rb") as fh:
        return net.query(f"vrsim/scenario/start?source={path};base_dir={folder}", fh.read())


def _run_through_services(net, folder, name):
    """Start scenario `name` on the services once they are free and wait until the monitor holds every
    tick: the start reply, the final status and the monitor's report."""
    net.wait_status(lambda s: s["state"] in ("idle", "finished", "failed", "stopped"))
    ok, started = start(net, folder, name)
    assert ok, started
    status = net.wait_status(lambda s: s["run_id"] == started["run_id"] and s["monitor_ticks"] == s["ticks"]
                             and s["state"] in ("finished", "failed"))
    assert status["state"] == "finished", status
    ok, report = net.query("vrsim/tractor1/report")
    assert ok, report
    return started, status, report


def _vrsim_run(folder, name):
    """`vrsim run --json` of scenario `name` (its outputs in run-NAME beside it): the summary."""
    cli = subprocess.run([VRSIM, "run", os.path.join(folder, f"{name}.toml"), "--json", "--quiet", "--out",
                          os.path.join(folder, f"run-{name}")], capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    return json.loads(cli.stdout)


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_controller_kind_through_the_services_matches_vrsim_run(net, folder, name):
    started, status, report = _run_through_services(net, folder, name)
    ok, state = net.query("vrsim/tractor1/control/state")
    assert ok and state["run_id"] == started["run_id"] and state["next_tick"] == status["ticks"], state
    assert set(state["core"]) == {"loop", "last_rate_kg_ha", "tuner", "sections", "meter_rev", "passes"}
    assert state["core"]["passes"] is None   # no [response] that follows the passes
    assert state["core"]["meter_rev"] > 10   # the shaft's position, carried batch after batch
    # Section control's memory came along, batch after batch: its ticks, and the coverage map, packed.
    sections = state["core"]["sections"]
    assert sections["tick"] == status["ticks"] and sections["passes"]["next_id"] > 1
    assert set(sections["engine"]) >= {"treated", "gates", "last_command"}
    if name == "smith":   # the tuner moved the look-ahead, batch after batch
        assert state["core"]["tuner"]["updates"] > 0
        assert set(state["core"]["loop"]["controller"]) == {"pid_v", "model_x", "model_delay_rpm"}
    else:
        assert state["core"]["loop"]["controller"]["error_sum_rpm"][0] != 0.0
    expected = _vrsim_run(folder, name)
    assert report["ticks"] == expected["ticks"] > 1000 and report["scenario"] == f"svc-{name}"
    assert report["missing_ticks"] == [] and report["complete"] is True
    assert_same_summary(report, expected, MONITOR_KEYS)


def test_a_drive_per_section_through_the_services_matches_vrsim_run(net, folder):
    """``section_drives``: the monitor rebuilds each drive's product and target from its records
    (`messages.RateSample.drive_kg`, `messages.ShaftState.drive_target_rpm`), so its report is `vrsim
    run`'s: each section's strip its own drive's product, a tick with one drive on its bound limited."""
    started, _, report = _run_through_services(net, folder, "drives")
    ok, rates = net.query(f"vrsim/tractor1/monitor/records?run_id={started['run_id']};stream=rate;count=5")
    assert ok and all(len(r["drive_kg"]) == 4 and "side_steps_on" not in r for r in rates), rates
    expected = _vrsim_run(folder, "drives")
    assert report["ticks"] == expected["ticks"] > 1000 and report["complete"] is True
    assert expected["limited_time_pct"] > 5 and expected["limited_area_pct"] > 5
    assert_same_summary(report, expected, MONITOR_KEYS)
    # `vrsim report` of the records: the same error split (each drive's reference meters) as the run's
    out = os.path.join(folder, "report-drives")
    p = subprocess.run([VRSIM, "report", "--db", net.db, "--run", started["run_id"], "--out", out],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    split = [_split_table(os.path.join(d, "report.html")) for d in (out, os.path.join(folder, "run-drives"))]
    assert split[0] == split[1] and "metering" in split[0]


def test_a_pwm_sprayer_through_the_services_matches_vrsim_run(net, folder):
    """``sprayer`` with PWM: the controller service closes each section's flow loop on the sprayer's own
    plant and the monitor rebuilds each section's product, so its report is `vrsim run`'s."""
    _, _, report = _run_through_services(net, folder, "sprayer")
    expected = _vrsim_run(folder, "sprayer")
    assert report["ticks"] == expected["ticks"] > 1000 and report["complete"] is True
    assert abs(expected["mass_balance_pct"]) < 5
    assert_same_summary(report, expected, MONITOR_KEYS)


def test_a_spinner_whose_sides_shorten_in_steps_through_the_services_matches_vrsim_run(net, folder):
    """``spinner`` under coverage control: the controller service publishes each side's steps on
    (`messages.RateSample.side_steps_on`) and the monitor rebuilds the run's ``side_steps_on`` from
    them, so its report throws each side as far as `vrsim run` does, not whole."""
    started, _, report = _run_through_services(net, folder, "spinner")
    ok, rates = net.query(f"vrsim/tractor1/monitor/records?run_id={started['run_id']};stream=rate;"
                          f"count={report['ticks']}")
    assert ok and len(rates) == report["ticks"], rates
    steps = np.array([r["side_steps_on"] for r in rates])
    assert steps.shape == (report["ticks"], 2) and ((steps > 0) & (steps < 4)).any()  # sides shortened
    expected = _vrsim_run(folder, "spinner")
    assert report["ticks"] == expected["ticks"] > 1000 and report["complete"] is True
    assert_same_summary(report, expected, MONITOR_KEYS)


def _split_table(path: str) -> str:
    """The error split's table of a report.html."""
    with open(path) as fh:
        page = fh.read()
    start = page.index("<table><tr><th>cause</th>")
    return page[start:page.index("</table>", start)]


def test_user_code_outside_the_allowed_folders_is_refused(net, folder, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.copy(os.path.join(folder, "my_controller.py"), elsewhere)
    with open(os.path.join(folder, "user.toml")) as fh:  # its map stays in the data root (`folder`)
        text = fh.read().replace('file = "map.tif"', f'file = "{os.path.join(folder, "map.tif")}"')
    (elsewhere / "user.toml").write_text(text)
    net.wait_status(lambda s: s["state"] in ("idle", "finished", "failed", "stopped"))
    ok, reply = start(net, str(elsewhere), "user")
    assert not ok
    assert f"{elsewhere}/my_controller.py" in reply["error"] and "--allow-user-code" in reply["error"]
    assert folder in reply["error"]


def test_serve_all_with_a_user_controller_scenario_allows_its_folder(folder):
    """`vrsim serve all SCENARIO`: the user named the scenario, so its controller file may run."""
    server = ServeAll(folder, "user.toml")
    try:
        server.wait_ready()
        status = server.wait_status(lambda s: s["state"] in ("finished", "failed")
                                    and s["monitor_ticks"] == s["ticks"])
        assert status["state"] == "finished" and status["scenario"] == "svc-user", status
    finally:
        assert server.stop() == 0, server.output()
