"""Bounded input and clear messages, checked before any work: message and batch caps, the scenario
loader's ranges and nesting, the run's memory estimate, the data root, quoted file content, the
deferred-reply timeout. (Over a real bus with memory measured: tests/integration/test_secure_serve_all.py.)"""

from __future__ import annotations

import os

import numpy as np
import orjson
import pytest

from vrsim.common import MapError, ScenarioError, ServiceError, files
from vrsim.services.bus import messages
from vrsim.services.bus.serving import within
from vrsim.services.sim import scenario
from vrsim.services.sim.section_landing import section_strips
from vrsim.services.sim.sections import SectionStates
from vrsim.services.sim.world import build_world

FIELD = '[field]\nrectangle = { width_m = 36.0, length_m = 60.0, lat = 52.1, lon = 11.6 }\n'
MAP = '[map]\nsynthetic = "uniform"\n'


# ------------------------------------------------------------------------------------- messages
def test_a_points_body_with_too_many_values_is_refused_before_parsing():
    body = b'{"x": [' + b"1.0," * 2_500_000 + b'1.0], "y": [1.0]}'  # 10 MB: 2.5 M values
    with pytest.raises(ServiceError, match=r"more than 250,000 points in one query .*, refused before "):
        messages.decode_points(body)
    with pytest.raises(ServiceError, match="a payload of 200 bytes is over the 100-byte limit"):
        messages.decode_points(b" " * 200, max_bytes=100)


def test_a_batch_with_too_many_records_or_bytes_is_refused_before_parsing():
    with pytest.raises(ServiceError, match="Pose batch: more than 10,000 records, refused before parsing"):
        messages.decode_batch(messages.Pose, b"[" + b"{}," * 20_000 + b"{}]")
    with pytest.raises(ServiceError, match=r"over the 8,388,608-byte limit"):
        messages.decode_batch(messages.Pose, b" " * (messages.MAX_MESSAGE_BYTES + 1))


def test_rates_are_encoded_in_chunks_as_one_array():
    n = 2 * messages.ENCODE_CHUNK + 3
    rate = np.linspace(0.0, 300.0, n)
    rate[7] = np.nan
    inside = np.ones(n, bool)
    inside[messages.ENCODE_CHUNK] = False
    rows = np.arange(n)
    doc = orjson.loads(messages.encode_rates(rate, rate, "kg/ha", inside, rows, rows))
    assert len(doc) == n and doc[7]["rate_kg_ha"] is None and doc[-1]["row"] == n - 1
    assert doc[messages.ENCODE_CHUNK] == {"rate_kg_ha": None, "rate": None, "rate_unit": "kg/ha",
                                          "inside": False, "row": None, "col": None}


# ------------------------------------------------------------------------------------- scenarios
@pytest.mark.parametrize("text, message", [
    (f"seed = 2147483648\n{FIELD}{MAP}", "s.toml: seed must be in [0, 2147483647], got 2147483648"),
    (f"{FIELD}{MAP}[timing]\ncontrol_period_s = 100.0\nplant_step_s = 0.001\n",
     "s.toml: [timing] control_period_s must be in [0.001, 1] s (SUMO's step), got 100.0"),
    (f"{FIELD}{MAP}[timing]\ncontrol_period_s = 0.0001\nplant_step_s = 0.0001\n",
     "s.toml: [timing] control_period_s must be in [0.001, 1] s"),
    (f"{FIELD}{MAP}[timing]\nmax_sim_time_s = 1e300\n",
     "s.toml: [timing] max_sim_time_s must be in [control_period_s, 1e+06] s, got 1e+300"),
    (f"{FIELD}{MAP}[timing]\nmax_sim_time_s = 0.001\n", "[timing] max_sim_time_s must be in"),
    (f'{FIELD}{MAP}[controller]\ngains = "manual"\nkp = 1e308\n',
     "s.toml: [controller] controller pid kp must be a number in [0, 1e+06], got 1e+308"),
    ("x = " + "[" * 5000 + "]" * 5000 + "\n", "s.toml: not a scenario: values nested too deeply"),
    ("#" * (files.BYTE_CAPS["toml"] + 1), "is over the 1,048,576-byte cap for scenario files"),
])
def test_the_loader_refuses_out_of_range_values_naming_file_table_and_key(text, message):
    with pytest.raises(ScenarioError) as err:
        scenario.parse(text, "s.toml")
    assert message in str(err.value), str(err.value)


@pytest.mark.parametrize("make, what", [(os.mkfifo, "is a FIFO"), (lambda p: os.symlink("/dev/zero", p),
                                                                     "is a device")])
def test_a_scenario_file_that_is_a_fifo_or_a_device_is_refused_at_once(tmp_path, make, what):
    path = str(tmp_path / "s.toml")
    make(path)
    with pytest.raises(ScenarioError, match=f"s.toml: {what}"):
        scenario.load(path)


def test_an_unreachable_time_limit_is_refused_when_the_world_is_built():
    sc = scenario.parse(f"{FIELD}{MAP}[timing]\nmax_sim_time_s = 20.0\n", "s.toml")
    with pytest.raises(ScenarioError, match=r"s.toml: \[timing\] max_sim_time_s = 20 s cannot be met: "
                                            r"the [\d,]+ m path takes at least [\d.]+ s at the tractor"):
        build_world(sc)


def test_a_run_too_big_for_memory_is_refused_before_its_path_is_planned():
    big = '[field]\nrectangle = { width_m = 9000.0, length_m = 9000.0, lat = 52.1, lon = 11.6 }\n'
    fine = '[map]\nsynthetic = "uniform"\ncell_size_m = 0.25\n'   # over a billion cells
    sc = scenario.parse(f"{big}{fine}[implement]\nwidth_m = 1.0\n", "s.toml")
    with pytest.raises(ScenarioError, match=r"s.toml: \[field\]: a run of about [\d,]+ ticks \([\d,]+ km at "
                                            r"2.5 m/s, 0.05 s per tick\) over a map of about [\d,]+ cells of "
                                            r"0.25 m needs about [\d,.]+ GB, more than the [\d,.]+ GB"):
        build_world(sc)


# ------------------------------------------------------------------------------------- data root
def test_paths_outside_the_root_are_refused_alike_whether_they_exist_or_not(tmp_path):
    root, outside = tmp_path / "root", tmp_path / "outside"
    root.mkdir()
    outside.mkdir()
    (outside / "secret.csv").write_text("password,1234\n")
    (root / "map.csv").write_text("x,y,rate\n")
    (root / ".vrsim").mkdir()
    (root / ".vrsim" / "dictionary.txt").write_text("operator:pw\n")
    os.symlink(outside / "secret.csv", root / "link.csv")
    os.symlink(outside / "secret.csv", root / "map.dbf")  # a sibling a reader would open
    (root / "field").mkdir()
    os.symlink(outside / "secret.csv", root / "field" / "TASKDATA.XML")

    def check(path):
        return files.check_within(str(path), str(root), MapError, private=(str(root / ".vrsim"),))

    assert check(root / "other.tif") == str(root / "other.tif")
    for bad in (outside / "secret.csv", outside / "missing.csv", root / ".." / "outside" / "secret.csv",
                root / "link.csv", root / ".vrsim" / "dictionary.txt", root / "map.csv", root / "field"):
        with pytest.raises(MapError) as err:
            check(bad)
        assert str(err.value).startswith(f"{bad}: outside the data root {root}")
        assert "1234" not in str(err.value) and "password" not in str(err.value)


def test_file_content_is_quoted_only_when_allowed():
    assert files.shown("a,b") == "'a,b'"
    files.show_content(False)
    try:
        assert files.shown("password,1234") == "(not shown)"
    finally:
        files.show_content(True)


# ------------------------------------------------------------------------------------- the rest
def test_landing_strips_never_join_across_a_gap():
    """A record with a gap (the monitor's after it was down, ``track["tick"]``) lands each stretch on
    its own: no strip joins the ticks before the gap to those after it."""
    n = 10
    track = {"time_s": 0.05 * np.arange(n), "x_m": np.arange(n, dtype=float), "y_m": np.zeros(n),
             "heading_rad": np.zeros(n)}
    states = SectionStates(np.ones((n, 1), bool), np.array([12.0]), np.array([0.0]), np.zeros(n, int))
    kg = np.ones(n)
    whole = section_strips(track, kg, states, 0.0, 0.05, cell_m=100.0)
    assert len(whole.mass_kg) == 1 and whole.mass_kg.tolist() == [10.0]
    gapped = section_strips(dict(track, tick=np.r_[0:4, 9:15]), kg, states, 0.0, 0.05, cell_m=100.0)
    assert gapped.mass_kg.tolist() == [4.0, 6.0]
    assert gapped.x0_m.tolist()[1] == 4.0


def test_within_refuses_work_that_takes_too_long_and_passes_errors_on():
    import threading

    release = threading.Event()
    with pytest.raises(ServiceError, match="building: took longer than 0.1 s; refused"):
        within(0.1, release.wait, "building")
    release.set()
    assert within(5.0, lambda: 42, "x") == 42
    with pytest.raises(ScenarioError, match="bad"):
        within(5.0, lambda: (_ for _ in ()).throw(ScenarioError("bad")), "x")


def test_max_input_mb_raises_every_cap_and_lowers_none():
    import argparse

    from vrsim.services.cli.options import apply_input_cap

    before = dict(files.BYTE_CAPS)
    try:
        apply_input_cap(argparse.Namespace(max_input_mb=300.0))
        assert files.BYTE_CAPS["csv"] == files.BYTE_CAPS["toml"] == 300 * files.MiB
        assert files.BYTE_CAPS["geotiff"] == before["geotiff"]
        with pytest.raises(Exception, match="--max-input-mb -1: must be"):
            apply_input_cap(argparse.Namespace(max_input_mb=-1.0))
    finally:
        files.BYTE_CAPS.update(before)
