"""Section control through whole runs (real SUMO): coverage switching, latencies, per-section landing,
the error split, the machine check, and the outputs and refusals of `vrsim run`."""

import json
import os
import subprocess

import numpy as np
import pytest
import rasterio

from tests.conftest import VRSIM
from vrsim.common.section_masks import sections_from_masks
from vrsim.services.outputs.write import write_outputs
from vrsim.services.sim import accuracy, metrics
from vrsim.services.sim.error_split import error_split
from vrsim.services.sim.run import run
from vrsim.services.sim.scenario import load, parse, with_changes
from vrsim.services.sim.sections import switch_sections

FIELD = """
name = "{name}"
seed = 13
[field]
rectangle = {{ width_m = {width}, length_m = {length}, lat = 52.0, lon = 10.0 }}
headland_passes = 1
{heading}
[map]
cell_size_m = 2.0
{map}
[gnss]
kind = "rtk"
[output]
plots = {plots}
html = {plots}
"""
UNIFORM = 'synthetic = "uniform"\nparams = { rate_kg_ha = 180.0 }'
CHECKERS = 'synthetic = "checkerboard"\nparams = { square_m = 48.0, low_kg_ha = 120.0, high_kg_ha = 220.0 }'


def field(name="f", width=120.0, length=250.0, heading=None, rx=CHECKERS, plots=False):
    text = FIELD.format(name=name, width=width, length=length, map=rx, plots="true" if plots else "false",
                        heading="" if heading is None else f"heading_deg = {heading}")
    return parse(text, f"{name}.toml")


def oblique(**implement):
    return with_changes(field("oblique", heading=35.0), implement=implement) if implement \
        else field("oblique", heading=35.0)


def vrsim(*args):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=300)


def test_uniform_map_with_the_ideal_meter_lands_the_map():
    """Geometry and section control alone (the ideal meter, no speed change at swath ends: turns at
    the working speed) leave under 1 % overlap and at least 98.5 % of the worked ground within 10 %
    (98.84 % measured: within +-10 % counts the cells at the headland's edge that the sections' opening
    and closing leave partly bare, judged on the share swept)."""
    sc = with_changes(field("uniform", 160.0, 400.0, rx=UNIFORM), controller={"kind": "ideal"},
                      tractor={"turn_speed_m_s": 2.5})
    s = run(sc).summary
    assert s["overlap_area_pct"] < 1.0, s
    assert s["within_10pct_area_pct"] >= 98.5, s
    assert s["skip_area_pct"] < 1.0 and abs(s["mass_balance_pct"]) < 1.0, s


@pytest.fixture(scope="module")
def rectangle_ideal():
    """The accuracy library's plain rectangle, uniform map, ideal meter, turns at the default 1.2 m/s
    (the tractor speeds up to 2.5 m/s out of each headland turn)."""
    return run(load(os.path.join(accuracy.SCENARIO_DIR, "rectangle_uniform_ideal.toml")))


def test_sections_open_at_the_headland_edge_after_turns(rectangle_ideal):
    """Each section's product starts landing within half a map cell (1 m) of the treated headland's
    inner edge at every swath start: the look-ahead follows the turn's end and the speed-up (with the
    heading and speed held, the outer sections started up to 2.5 m late)."""
    result = rectangle_ideal
    track, gates = result.track, result.sections.actual
    time_s, y_m = np.asarray(track["time_s"]), np.asarray(track["y_m"])
    _, south, _, north = result.world.field.polygon.bounds
    headland_m = result.world.scenario.implement.width_m
    delay_s = result.world.scenario.implement.delivery_delay_s
    starts = np.flatnonzero(~gates[:-1].any(axis=1) & gates[1:].any(axis=1)) + 1
    late_m = []
    for start in starts[1:]:   # the first is the headland pass's own start
        first = start + np.argmax(gates[start:], axis=0)   # each section's first open tick
        landed_y = np.interp(time_s[first] + delay_s, time_s, y_m)
        from_south = landed_y.mean() < (south + north) / 2
        late_m.append(landed_y - (south + headland_m) if from_south else (north - headland_m) - landed_y)
    late_m = np.array(late_m)
    assert len(late_m) >= 6 and np.abs(late_m).max() <= 1.0, late_m.round(2)


@pytest.mark.xfail(strict=True, reason="issue #25's goal is out of the gated meter's reach on this field: "
                   "97.13 % of the worked ground within +-10 % (98.03 % of the fully covered cells). "
                   "Its headland corners put 0.88 % of the covered area outside "
                   "(one meter sharing product by width in a 6 m-radius turn: the outer end at twice the "
                   "centre's speed gets half the rate), the slow-down before each swath end within the "
                   "0.8 s delivery delay 0.65 % (band) and the headland's edge row 0.35 %, the corner "
                   "turns' slow-downs just outside the corners 0.10 % "
                   "(test_rectangle_ideal_outside_10_pct_is_corners_and_speed_changes)")
def test_rectangle_ideal_reaches_99_pct_within_10_pct(rectangle_ideal):
    assert rectangle_ideal.summary["within_10pct_area_pct"] >= 99.0


def _outside_10_pct_by_place(result) -> dict[str, float]:
    """The covered cells outside +-10 % of the prescription, by where they lie on a rectangle worked
    with one headland pass of the implement's width, as % of the covered area: the headland pass's
    corner squares, the band 2-10 m inside the headland's inner edge at the swath ends (where the
    tractor slows for the turn), that edge +-2 m (where the sections open and close), the rest."""
    grid, applied = result.world.grid, result.as_applied
    rx = grid.rates_kg_ha
    covered = result.in_field & (applied.coverage_fraction >= metrics.COVERED_FRACTION) & np.isfinite(rx)
    outside = covered & (np.abs(applied.applied_kg_ha - rx) > 0.10 * rx)
    west, south, east, north = result.world.field.polygon.bounds
    headland_m = result.world.scenario.implement.width_m
    x, y = np.meshgrid(*grid.cell_centres())
    across = np.minimum(x - west, east - x)   # from the nearer long side, m
    along = np.minimum(y - south, north - y)  # from the nearer end, m
    corners = (across < headland_m) & (along < headland_m)
    edge = ~corners & (np.abs(along - headland_m) <= 2.0)
    band = ~corners & ~edge & (along > headland_m) & (along < headland_m + 10.0)
    places = {"corners": corners, "edge": edge, "band": band, "rest": ~(corners | edge | band)}
    return {name: 100.0 * np.count_nonzero(outside & at) / np.count_nonzero(covered)
            for name, at in places.items()}


def test_rectangle_ideal_outside_10_pct_is_corners_and_speed_changes(rectangle_ideal):
    """Where issue #25's 2 % lie (the ideal meter, so geometry and section control alone): the headland
    pass's four corners, 0.88 % of the covered area, where one meter shares product by width in a
    6 m-radius turn (the outer end moves at twice the centre's speed: only offsets within about 0.6 m
    of the centre get within 10 % of the rate; the pivoting inner end is closed by the slow speed
    cutoff), a limit of the gated meter; the swath ends' slow-down (product metered at 2.5 m/s lands
    during the slow-down to 1.2 m/s 0.8 s later, about +45 % on a row of cells, 0.65 %), and the
    headland's edge where the sections close while the tractor slows and open while the speed-up out
    of the turn ends within their 1.8 s look-ahead (0.35 %). The rest (0.10 %) is the corner turns'
    own slow-down rows just outside the corner squares; the field between is clean."""
    share = _outside_10_pct_by_place(rectangle_ideal)
    assert share["corners"] > 0.8 and share["band"] > 0.5 and share["edge"] > 0.2, share
    assert share["rest"] < 0.15, share


def test_the_slow_speed_cutoff_closes_the_pivoting_inner_sections(rectangle_ideal):
    """On the run's true track, no section is commanded on while its own ground speed (the speed minus
    the yaw rate times its offset) is at most ``section_min_speed_m_s``; in the headland pass's
    6 m-radius corners the innermost section's is, so the cutoff closes it there while the path works."""
    world = rectangle_ideal.world
    imp = world.scenario.implement
    states = switch_sections(rectangle_ideal.track, imp, world.field.polygon, world.path,
                             min(world.grid.cell_size))
    slow = states.motion.ground_speed_m_s(imp.section_offsets_m) <= imp.section_min_speed_m_s
    working = np.asarray(rectangle_ideal.track["implement_on"], bool)
    assert not (states.commanded & slow).any()
    assert np.count_nonzero(slow & working[:, None]) > 40, np.count_nonzero(slow & working[:, None])


def test_rectangle_ideal_without_speed_changes_keeps_only_the_corners():
    """Turns at the working speed (no slow-down, no speed-up): the band and the edge are clean, and the
    corners are what is left among the fully covered cells. Over the worked ground (bare and partly
    covered cells counted) 97.69 % is within +-10 %: the corners 1.41 %, the headland's edge 0.70 %
    (cells the sections' opening and closing leave partly bare) and the band 0.17 %."""
    scenario = load(os.path.join(accuracy.SCENARIO_DIR, "rectangle_uniform_ideal.toml"))
    result = run(with_changes(scenario, tractor={"turn_speed_m_s": 2.5}))
    share = _outside_10_pct_by_place(result)
    assert share["corners"] > 0.8 and share["band"] == 0.0, share
    assert share["edge"] + share["rest"] < 0.2, share
    assert result.summary["within_10pct_area_pct"] > 97.5, result.summary


def test_oblique_headland_needs_coverage_control():
    """Swaths at 35 degrees to the headland, 6 sections, the paper's PID: coverage control keeps the
    mass balance within 3 %; the boundary rule (a section on while its centre is in the field)
    over-applies where swath ends cross the treated headland."""
    coverage = run(oblique(sections=6)).summary
    boundary = run(oblique(sections=6, section_control="boundary")).summary
    assert abs(coverage["mass_balance_pct"]) <= 3.0, coverage
    assert boundary["mass_balance_pct"] > abs(coverage["mass_balance_pct"]) + 5.0, boundary
    assert boundary["overlap_area_pct"] > 5 * coverage["overlap_area_pct"]
    assert coverage["within_10pct_area_pct"] > boundary["within_10pct_area_pct"]


def test_longer_latencies_give_more_overlap_and_skips():
    """Skips grow with the latency throughout; overlap up to 3 s. Beyond, the look-ahead extrapolates
    the acceleration and yaw rate of a moment over seconds in which the tractor has long changed them
    (8.8 s ahead: a turn's yaw rate turns the predicted strip by 100 degrees), and where product lands
    twice is no longer ordered by the latency; that it is far off shows in the skips."""
    figures = [run(with_changes(oblique(section_on_delay_s=d, section_off_delay_s=d),
                                controller={"kind": "ideal"})).summary for d in (0.3, 1.0, 3.0, 8.0)]
    for key, upto in (("overlap_area_pct", 3), ("skip_area_pct", 4), ("overlap_kg", 3)):
        values = [f[key] for f in figures[:upto]]
        assert np.all(np.diff(values) > 0), (key, values)


@pytest.mark.parametrize("on_s, off_s", [(1.0, 0.6), (0.93, 0.37)])
def test_gates_switch_the_configured_latency_after_the_commands(on_s, off_s):
    result = run(oblique(section_on_delay_s=on_s, section_off_delay_s=off_s))
    period = result.world.scenario.timing.control_period_s
    commanded, gates = result.sections.commanded, result.sections.actual
    dc = np.diff(commanded.astype(np.int8), axis=0, prepend=0)
    dg = np.diff(gates.astype(np.int8), axis=0, prepend=0)
    switched = 0
    for s in range(gates.shape[1]):
        for delay_s, edge in ((on_s, 1), (off_s, -1)):
            ticks = np.flatnonzero(dg[:, s] == edge)
            k = round(delay_s / period)
            assert abs(k * period - delay_s) <= period  # within one tick of the configured latency
            assert (dc[ticks - k, s] == edge).all()  # the command changed exactly k ticks before
            switched += ticks.size
    assert switched > 100


def test_outputs_carry_sections_passes_and_the_error_split(tmp_path):
    result = run(with_changes(oblique(), output={"plots": True, "html": True, "track": "csv"}))
    paths = write_outputs(result, str(tmp_path))
    lines = open(paths["track.csv"]).read().splitlines()
    header = lines[0].split(",")
    assert header[-2:] == ["sections_on", "section_mask"]
    rows = [line.split(",") for line in lines[1:]]
    gates = sections_from_masks([r[-1] for r in rows], 6)
    np.testing.assert_array_equal(gates, result.control["sections_on"])
    np.testing.assert_array_equal([int(r[-2]) for r in rows], gates.sum(axis=1))
    assert 0 < gates.sum(axis=1).mean() < 6
    with rasterio.open(paths["passes.tif"]) as ds:
        passes = ds.read(1)
        assert ds.tags()["unit"] == "passes" and ds.crs is not None
    np.testing.assert_array_equal(passes, result.as_applied.pass_count)
    assert passes.max() >= 2 and (passes[result.in_field] == 1).mean() > 0.9
    page = open(paths["report.html"]).read()
    for text in ("Where the error comes from", "machine limits", "metering", "sections.png", "Machine check",
                 "Overlap area", "Section widths"):
        assert text in page, text
    summary = json.load(open(paths["summary.json"]))
    assert summary["sections"] == 6 and summary["section_widths_m"] == [2.0] * 6
    parts = error_split(result)
    assert sum(p.mass_balance_pct for p in parts) == pytest.approx(summary["mass_balance_pct"], abs=1e-9)
    assert sum(p.mae_kg_ha for p in parts) == pytest.approx(summary["mae_kg_ha"], abs=1e-9)
    assert parts[0].share_pct > 50  # obliquely crossed squares: most of the error is geometry
    ideal = error_split(run(with_changes(oblique(), controller={"kind": "ideal"})))
    # The ideal meter meters exactly: nothing left for metering (to rounding: the references land
    # through maps.ColumnDeposit, the run through maps.AsApplied, summing in another order).
    assert ideal[-1].mass_balance_pct == pytest.approx(0.0, abs=1e-9)
    assert ideal[-1].mae_kg_ha == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("kind", ["gated_meter", "section_drives"])
def test_the_error_split_adds_up_and_leaves_an_ideal_meter_nothing_for_metering(kind):
    """The reference meters are the run's machine kind (a drive per section: each drive at its own
    section's rate and speed, its product on its own strip): the parts add up to the run's figures,
    and with the ideal controller nothing is left for metering, for every kind."""
    pid = run(oblique(kind=kind))
    parts = error_split(pid)
    assert sum(p.mass_balance_pct for p in parts) == pytest.approx(pid.summary["mass_balance_pct"], abs=1e-9)
    assert sum(p.mae_kg_ha for p in parts) == pytest.approx(pid.summary["mae_kg_ha"], abs=1e-9)
    assert parts[-1].mae_kg_ha != 0.0   # the PID's lag costs something
    ideal = run(with_changes(oblique(kind=kind), controller={"kind": "ideal"}))
    parts = error_split(ideal)
    assert sum(p.mae_kg_ha for p in parts) == pytest.approx(ideal.summary["mae_kg_ha"], abs=1e-9)
    assert parts[-1].mass_balance_pct == pytest.approx(0.0, abs=1e-9)
    assert parts[-1].mae_kg_ha == pytest.approx(0.0, abs=1e-9)


def test_unequal_sections_are_named_and_land_their_share():
    s = run(oblique(sections=5, section_widths_m=[3.0, 2.0, 2.0, 2.0, 3.0])).summary
    assert s["sections"] == 5 and s["section_widths_m"] == [3.0, 2.0, 2.0, 2.0, 3.0]
    assert abs(s["mass_balance_pct"]) <= 3.0


def test_machine_check_before_the_run_and_the_limited_figures(tmp_path):
    """An 18 m boom at 3.6 m/s on a map up to 260 kg/ha asks 202 rpm of a 150 rpm shaft."""
    text = FIELD.format(name="too_fast", width=144.0, length=250.0, heading="", plots="false",
                        map=CHECKERS.replace("120.0", "140.0").replace("220.0", "260.0"))
    text += "[implement]\nwidth_m = 18.0\n[tractor]\nworking_speed_m_s = 3.6\nspeed_variation_pct = 0.0\n"
    path = tmp_path / "too_fast.toml"
    path.write_text(text)
    p = vrsim("run", str(path), "--check")
    assert p.returncode == 3, p.stderr   # the check's "no"
    assert "CANNOT apply the whole map" in p.stdout and "202.2 rpm of a 5-150 rpm shaft" in p.stdout
    assert "Above 2.67 m/s" in p.stdout
    # What to change: the speeds at which it can, or a meter constant that can at these speeds.
    assert "keep the working speeds within 0.17-2.67 m/s" in p.stdout, p.stdout
    assert "set [implement] kg_per_rev to 0.6739-10.89 kg/rev" in p.stdout
    assert "to apply it at 3.60-3.60 m/s" in p.stdout
    assert not (tmp_path / "runs").exists()
    p = vrsim("run", str(path), "--check", "--json")
    check = json.loads(p.stdout)
    assert check["can_apply"] is False and check["max_speed_m_s"] == pytest.approx(2.67, abs=0.01)
    p = vrsim("run", str(path), "--quiet", "--json", "--out", str(tmp_path / "o"))
    s = json.loads(p.stdout)
    assert s["limited_time_pct"] > 20 and s["limited_area_pct"] > 20 and s["mass_balance_pct"] < -5
    assert s["max_speed_m_s"] == pytest.approx(check["max_speed_m_s"])
    p = vrsim("run", str(path), "--quiet", "--out", str(tmp_path / "o2"))
    assert "CANNOT apply the whole map" in p.stdout  # in every run's printout


@pytest.mark.parametrize("line, message", [
    ("section_on_delay_s = -0.5", "section_on_delay_s must be a number in [0, 30] s, got -0.5"),
    ("section_off_delay_s = nan", "section_off_delay_s must be finite, got nan"),
    ("section_on_delay_s = 31.0", "section_on_delay_s must be a number in [0, 30] s, got 31.0"),
    ("section_overlap_pct = 101.0", "section_overlap_pct must be a number in [0, 100] %, got 101.0"),
    ("boundary_overlap_pct = -1.0", "boundary_overlap_pct must be a number in [0, 100] %, got -1.0"),
    ("section_widths_m = [2.0, 4.0, 4.0]",
     "section_widths_m [2.0, 4.0, 4.0] add up to 10 m, not width_m=12.0"),
    ("sections = 129", "sections must be an integer in [1, 128], got 129"),
    ("section_control = \"sometimes\"",
     "section_control must be one of coverage, boundary, off, got 'sometimes'"),
])
def test_bad_section_settings_exit_2_naming_file_table_key_and_value(tmp_path, line, message):
    path = tmp_path / "bad.toml"
    path.write_text(FIELD.format(name="bad", width=72.0, length=150.0, heading="", map=UNIFORM, plots="false")
                    + f"[implement]\n{line}\n")
    p = vrsim("run", str(path), "--quiet", "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert str(path) in p.stderr and "[implement]" in p.stderr and message in p.stderr, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
