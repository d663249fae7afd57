"""Machine kinds: the ``[implement] kind`` registry (keys in `vehicle.machines`, run-time parts in
`services.sim.machines`), read from scenario files and refused with one line when wrong."""

import dataclasses
import subprocess

import pytest

from common import ScenarioError, VehicleError
from services.sim.machines import Machine, machine_for, machine_kinds, register_machine
from services.sim.scenario import as_dict, load, parse, to_toml, with_changes
from tests.conftest import VRSIM
from vehicle import Implement
from vehicle.machines import SPECS, GatedMeter, MachineSpec, register_spec


def test_the_default_machine_is_the_gated_meter_and_its_table_is_flat():
    sc = load("default")
    assert sc.implement.kind == "gated_meter" and sc.implement.machine == GatedMeter()
    assert as_dict(sc)["implement"]["kind"] == "gated_meter" and "machine" not in as_dict(sc)["implement"]
    assert 'kind = "gated_meter"' in to_toml(sc) and parse(to_toml(sc)).implement == sc.implement
    assert isinstance(machine_for(sc.implement), Machine) and machine_for(sc.implement).drives == 1


def test_every_kind_with_keys_runs_and_every_run_time_kind_has_keys():
    assert set(machine_kinds()) == set(SPECS)


def test_a_kind_registers_once_and_only_with_its_keys():
    with pytest.raises(ValueError, match="registered twice"):
        register_machine(type("Again", (), {"kind": "gated_meter"}))
    with pytest.raises(ValueError, match="has no keys"):
        register_machine(type("Nowhere", (), {"kind": "nowhere"}))
    with pytest.raises(VehicleError, match="registered twice"):
        register_spec(dataclasses.make_dataclass("Twice", [], bases=(MachineSpec,), frozen=True,
                                                 namespace={"KIND": "gated_meter"}))


def test_an_implement_refuses_keys_of_another_kind_as_its_machine():
    other = dataclasses.make_dataclass("Other", [], bases=(MachineSpec,), frozen=True,
                                       namespace={"KIND": "x"})
    with pytest.raises(VehicleError, match="is not of kind 'gated_meter'"):
        Implement(machine=other())


@pytest.mark.parametrize("table, message", [
    ('kind = "hovercraft"', "[implement] Implement: kind must be one of gated_meter"),
    ("kind = 3", "[implement] Implement: kind must be one of gated_meter"),
    ("rollers = 2", "[implement] unknown key 'rollers' (known: "),
    ("machine = {}", "[implement] unknown key 'machine'"),
])
def test_a_bad_implement_table_is_one_line_naming_key_and_value(table, message):
    with pytest.raises(ScenarioError) as err:
        parse(f"[implement]\n{table}\n", "x.toml")
    assert str(err.value).startswith("x.toml: ") and message in str(err.value)


def test_with_changes_reads_the_kind_like_a_file():
    sc = with_changes(load("default"), implement={"kind": "gated_meter", "width_m": 18.0})
    assert (sc.implement.kind, sc.implement.width_m) == ("gated_meter", 18.0)
    with pytest.raises(ScenarioError, match="kind must be one of"):
        with_changes(sc, implement={"kind": "hovercraft"})


def test_an_unknown_kind_on_the_command_line_exits_2_with_one_line(tmp_path):
    out = subprocess.run([VRSIM, "run", "--quiet", "--set", "implement.kind=hovercraft", "--out",
                          str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert "[implement] Implement: kind must be one of gated_meter" in out.stderr
    assert "hovercraft" in out.stderr
