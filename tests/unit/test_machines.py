"""Machine kinds: the ``[implement] kind`` registry (keys in `vehicle.machines`, run-time parts in
`services.sim.machines`), read from scenario files and refused with one line when wrong."""

import dataclasses
import subprocess

import numpy as np
import pytest
import shapely

from tests.conftest import VRSIM
from vrsim.common import ScenarioError, VehicleError
from vrsim.maps import AsApplied, synthetic
from vrsim.services.sim.machines import Machine, machine_for, machine_kinds, register_machine
from vrsim.services.sim.scenario import load, parse, with_changes
from vrsim.services.sim.scenario_toml import as_dict, to_toml
from vrsim.services.sim.section_landing import StripPlan
from vrsim.services.sim.sections import SectionStates, switch_sections
from vrsim.services.sim.sections.motion import Motion
from vrsim.vehicle import Implement
from vrsim.vehicle.machines import SPECS, GatedMeter, MachineSpec, SectionDrives, register_spec


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


def test_one_registration_names_keys_run_time_part_and_footprint_and_refuses_what_disagrees():
    from vrsim.maps.footprint import FOOTPRINTS, Strips
    from vrsim.services.sim.machines.registry import MACHINES

    for kind, machine in MACHINES.items():   # the three registries hold every kind's one entry
        assert SPECS[kind] is machine.keys and FOOTPRINTS[machine.footprint.kind] is machine.footprint
    other = dataclasses.make_dataclass("Other", [], bases=(MachineSpec,), frozen=True,
                                       namespace={"KIND": "y"})
    vehicles = register_spec(dataclasses.make_dataclass("Vehicles", [], bases=(MachineSpec,), frozen=True,
                                                        namespace={"KIND": "y"}))
    before = (dict(SPECS), dict(MACHINES), dict(FOOTPRINTS))
    try:
        with pytest.raises(ValueError, match="has no keys"):    # keys of another kind
            register_machine(type("Mislabelled", (Machine,), {"kind": "x", "keys": other}))
        with pytest.raises(ValueError, match="not the ones registered"):   # keys other than vehicle's
            register_machine(type("Twin", (Machine,), {"kind": "y", "keys": other}))
        with pytest.raises(ValueError, match="footprint"):    # a footprint name another class holds
            register_machine(type("Clash", (Machine,), {"kind": "y", "keys": vehicles,
                                                         "footprint": type("S", (), {"kind": Strips.kind})}))
        assert (dict(SPECS), dict(MACHINES), dict(FOOTPRINTS)) == before   # nothing half registered
    finally:
        assert SPECS.pop("y") is vehicles


def test_an_implement_refuses_keys_of_another_kind_as_its_machine():
    other = dataclasses.make_dataclass("Other", [], bases=(MachineSpec,), frozen=True,
                                       namespace={"KIND": "x"})
    with pytest.raises(VehicleError, match="is not of kind 'gated_meter'"):
        Implement(machine=other())


@pytest.mark.parametrize("table, message", [
    ('kind = "hovercraft"', "[implement] Implement: kind must be one of gated_meter"),
    ("kind = 3",
     "[implement] Implement: kind must be one of gated_meter, section_drives, spinner, sprayer, got 3"),
    ("turn_compensation = false",
     "[implement] turn_compensation is a key of kind 'section_drives', not of kind 'gated_meter' "
     "(got False)"),
    ('kind = "section_drives"\nturn_compensation = 1', "[implement] turn_compensation must be bool, got 1"),
    ('kind = "section_drives"\nsections = 64',
     "[implement] Implement: kind 'section_drives' supports at most 48 sections, got sections=64"),
    ("rollers = 2", "[implement] unknown key 'rollers' (known: "),
    ("machine = {}", "[implement] unknown key 'machine'"),
])
def test_a_bad_implement_table_is_one_line_naming_key_and_value(table, message):
    with pytest.raises(ScenarioError) as err:
        parse(f"[implement]\n{table}\n", "x.toml")
    assert str(err.value).startswith("x.toml: ") and message in str(err.value)


def test_with_changes_reads_the_kind_like_a_file():
    sc = with_changes(load("default"), implement={"kind": "section_drives", "turn_compensation": False})
    assert sc.implement.machine == SectionDrives(turn_compensation=False) and sc.implement.sections == 6
    back = with_changes(sc, implement={"kind": "gated_meter"})   # the old kind's keys go with it
    assert back.implement == load("default").implement
    assert parse(to_toml(sc)).implement == sc.implement
    with pytest.raises(ScenarioError, match="kind must be one of"):
        with_changes(sc, implement={"kind": "hovercraft"})


def _states(imp, n, actual=None, yaw_rate_rad_s=0.0, speed_m_s=2.0):
    """Section states of `n` ticks heading east at y = 0 (all gates open unless `actual`)."""
    zeros = np.zeros(n)
    motion = Motion(np.arange(n) * 0.1, zeros, zeros, np.full(n, speed_m_s), zeros,
                    np.full(n, yaw_rate_rad_s))
    actual = np.ones((n, imp.sections), bool) if actual is None else actual
    return SectionStates(actual, imp.section_widths, imp.section_offsets_m, np.zeros(n, int), None, motion)


def test_each_drive_meters_its_sections_share_and_turns_at_the_shafts_speed():
    imp = Implement(width_m=12.0, section_widths_m=[2.0, 4.0, 6.0], kind="section_drives")
    machine = machine_for(imp)
    assert machine.drives == 3 and machine.drive_share == pytest.approx([1 / 6, 1 / 3, 1 / 2])
    states = _states(imp, 4)
    rate = np.full((4, 3), 150.0)
    gated = machine_for(Implement(width_m=12.0, section_widths_m=[2.0, 4.0, 6.0]))
    one_shaft = gated.drive_targets(rate[:, :1], states)
    assert machine.drive_targets(rate, states) == pytest.approx(np.repeat(one_shaft, 3, axis=1))
    assert machine.combined(machine.drive_targets(rate, states)) == pytest.approx(one_shaft[:, 0])
    closed = states.actual.copy()
    closed[:, 1] = False
    assert (machine.drive_targets(rate, _states(imp, 4, closed))[:, 1] == 0).all()


def test_each_section_looks_up_at_its_own_landing_point_and_turns_at_its_own_speed():
    imp = Implement(width_m=12.0, sections=3, kind="section_drives")   # offsets 4, 0, -4 (left +)
    states = _states(imp, 2, yaw_rate_rad_s=0.1, speed_m_s=2.0)
    x, y, drive_x, drive_y = machine_for(imp).landing(states.motion, 0.0)
    assert drive_y == pytest.approx(np.tile([4.0, 0.0, -4.0], (2, 1)))
    assert drive_x == pytest.approx(np.repeat(x[:, None], 3, axis=1))
    # A left turn at 0.1 rad/s: the left (inner) section runs at 2 - 0.4, the right at 2 + 0.4 m/s.
    speeds = machine_for(imp).drive_speed_m_s(states.motion)
    assert speeds == pytest.approx(np.tile([1.6, 2.0, 2.4], (2, 1)))
    fixed = dataclasses.replace(imp, machine=SectionDrives(turn_compensation=False))
    assert machine_for(fixed).drive_speed_m_s(states.motion) == pytest.approx(np.full((2, 3), 2.0))
    # Beyond the pivot of a turn on the spot a section stands: no negative speed.
    pivot = _states(imp, 1, yaw_rate_rad_s=1.0, speed_m_s=2.0)
    assert machine_for(imp).drive_speed_m_s(pivot.motion)[0, 0] == 0.0


def test_each_sections_strip_carries_its_own_drives_product():
    imp = Implement(width_m=12.0, section_widths_m=[2.0, 4.0, 6.0], section_control="off",
                    kind="section_drives")
    n = 400
    t = np.arange(n) * 0.05
    track = {"time_s": t, "x_m": 500_010.0 + 2.5 * t, "y_m": np.full(n, 5_300_050.0),
             "heading_rad": np.zeros(n), "speed_m_s": np.full(n, 2.5), "implement_on": np.ones(n, bool)}
    states = switch_sections(track, imp, shapely.box(500_000, 5_300_000, 500_300, 5_300_100), None, 1.0)
    drive_kg = np.tile([0.001, 0.004, 0.003], (n, 1))   # kg per tick and drive
    plan = machine_for(imp).deposition(track, states, imp.delivery_delay_s, 0.05, 1.0)
    grid = synthetic.uniform((500_000.0, 5_300_000.0, 500_300.0, 5_300_100.0), "EPSG:32632", cell_size_m=1.0,
                             rate_kg_ha=0.0)
    applied = AsApplied(grid)
    applied.deposit(plan.footprint(), plan.mass_kg(drive_kg), pass_index=plan.pass_index)
    cells = grid.lookup(np.full(3, 500_040.5), 5_300_050.0 + np.array([5.5, 2.5, -2.5]))   # left to right
    # each strip: its drive's kg per tick over its width times 0.125 m of travel per tick
    want_kg_ha = [0.001 / (2 * 0.125) * 1e4, 0.004 / (4 * 0.125) * 1e4, 0.003 / (6 * 0.125) * 1e4]
    assert applied.applied_kg_ha[cells.row, cells.col] == pytest.approx(want_kg_ha, rel=1e-6)
    columns = plan.mass_kg(np.stack([drive_kg, 2 * drive_kg], axis=2))   # two controllers' columns
    assert columns[:, 1] == pytest.approx(2 * columns[:, 0])
    assert columns[:, 0] == pytest.approx(plan.mass_kg(drive_kg))
    closed = np.ones((n, 3), bool)
    closed[200, 2] = False
    shut = StripPlan.of(track, dataclasses.replace(states, actual=closed), imp.delivery_delay_s, 0.05, 1.0,
                        own_drives=True)
    with pytest.raises(ValueError, match="tick 200 meters product with its section's gate closed"):
        shut.mass_kg(drive_kg)


@pytest.mark.parametrize("settings, message", [
    (["implement.kind=hovercraft"],
     "[implement] Implement: kind must be one of gated_meter, section_drives, spinner, sprayer, "
     "got 'hovercraft'"),
    (["implement.turn_compensation=false"],
     "[implement] turn_compensation is a key of kind 'section_drives', not of kind 'gated_meter'"),
    (["implement.kind=section_drives", "implement.sections=49"],
     "[implement] Implement: kind 'section_drives' supports at most 48 sections, got sections=49"),
])
def test_a_bad_machine_on_the_command_line_exits_2_with_one_line(tmp_path, settings, message):
    sets = [arg for setting in settings for arg in ("--set", setting)]
    out = subprocess.run([VRSIM, "run", "--quiet", *sets, "--out", str(tmp_path)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and message in out.stderr
