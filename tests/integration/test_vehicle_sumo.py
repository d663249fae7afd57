"""Real SUMO (libsumo in this process, netconvert as a subprocess) driving real coverage paths."""

import os

import numpy as np
import pytest
import shapely

from tests.conftest import ROOT
from vrsim.common.errors import VehicleError
from vrsim.vehicle import DriveConfig, Field, SumoDriver, build_network, plan_coverage

DATA = os.path.join(ROOT, "tests", "data", "vehicle")
DRIVE = DriveConfig(working_speed_m_s=2.5, turn_speed_m_s=1.2, speed_variation_pct=5.0)


@pytest.fixture(scope="module")
def rect_run(rect_path, cache):
    with SumoDriver(rect_path, DRIVE, step_s=0.05, seed=1, cache_dir=cache) as drv:
        return drv.run_all()


def _kinds(path, run):
    return np.array(path.kinds())[run["segment_index"]]


def test_run_reaches_the_end_in_time_order(rect_path, rect_run):
    r = rect_run
    assert np.all(np.diff(r["time_s"]) > 0) and np.all(np.diff(r["s_m"]) >= -1e-9)
    assert r["s_m"][0] == pytest.approx(0.0, abs=1e-6)
    assert r["s_m"][-1] == pytest.approx(rect_path.length_m)
    # Took as long as the distance at about working speed, plus slower turns.
    assert rect_path.length_m / 2.7 < r["time_s"][-1] < rect_path.length_m / 1.2


def test_positions_lie_on_the_planned_swath_centre_lines(rect_path, rect_run):
    r = rect_run
    seg = r["segment_index"]
    checked = 0
    for i, s in enumerate(rect_path.segments):
        if s.kind != "swath":
            continue
        m = seg == i
        d = shapely.distance(shapely.points(r["x_m"][m], r["y_m"][m]), shapely.LineString(s.xy))
        assert d.max() < 0.05
        checked += m.sum()
    assert checked > 0.5 * len(seg)


def test_sumo_front_bumper_agrees_with_the_plan(rect_path, cache):
    """SUMO's own vehicle position (front bumper) is the plan at s + implement offset."""
    import libsumo

    with SumoDriver(rect_path, DRIVE, seed=1, cache_dir=cache) as drv:
        errs = []
        while not drv.finished:
            pose = drv.step()
            if drv.finished:
                break
            fx, fy = libsumo.vehicle.getPosition("tractor")
            s_front = pose.s_m + DRIVE.implement_offset_m
            seg = rect_path.segment_at(s_front)
            if s_front < rect_path.length_m and rect_path.segments[seg].kind == "swath":
                x, y, *_ = rect_path.locate(s_front)
                errs.append(np.hypot(fx - x, fy - y))
    assert len(errs) > 1000
    assert np.max(errs) < 0.25  # SUMO trims lanes at junctions by ~0.1 m; our mapping does not


def test_implement_off_in_turns_and_inside_the_field(rect_path, rect_run):
    r = rect_run
    kinds = _kinds(rect_path, r)
    assert not r["implement_on"][kinds == "turn"].any()
    assert r["implement_on"][kinds != "turn"][:-1].all()
    on = r["implement_on"]
    inside = shapely.contains_xy(rect_path.field.polygon, r["x_m"][on], r["y_m"][on])
    assert inside.all()


def test_speeds_stay_within_limits(rect_path, rect_run):
    r = rect_run
    v = r["speed_m_s"]
    assert v.min() >= 0 and v.max() <= DRIVE.max_speed_m_s + 1e-9
    # In turns (tractor front in the same turn) the turn speed holds.
    front = rect_path.segment_at(r["s_m"] + DRIVE.implement_offset_m)
    kinds = _kinds(rect_path, r)
    in_turn = (kinds == "turn") & (front == r["segment_index"])
    assert in_turn.sum() > 100 and v[in_turn].max() <= DRIVE.turn_speed_m_s + 1e-9
    # On swaths, away from the ends, the speed varies slowly within +-5 % of the working speed.
    seg = r["segment_index"]
    into = r["s_m"] - rect_path.seg_start_m[seg]
    left = rect_path.seg_length_m[seg] - into
    work = (kinds == "swath") & (into > 10.0) & (left > 15.0)
    assert work.sum() > 5000
    assert abs(np.mean(v[work]) - 2.5) < 0.1
    assert np.std(v[work]) > 0.01
    assert v[work].min() >= 2.5 * 0.95 - 1e-9
    accel = np.diff(v) / np.diff(r["time_s"])
    assert accel.max() <= DRIVE.accel_m_s2 + 1e-6
    assert accel.min() >= -DRIVE.decel_m_s2 - 1e-6


def test_same_seed_same_run_and_step_matches_run_all(rect_path, rect_run, cache):
    with SumoDriver(rect_path, DRIVE, seed=1, cache_dir=cache) as drv:
        poses = []
        while not drv.finished:
            poses.append(drv.step())
    assert len(poses) == len(rect_run["time_s"])
    # s_m too: `run_all` asks SUMO's route index only when the lane position leaves the lane, `step` always
    for key in ("time_s", "s_m", "x_m", "y_m", "speed_m_s", "heading_rad", "implement_on"):
        assert np.array_equal(np.array([getattr(p, key) for p in poses]), rect_run[key]), key
    with SumoDriver(rect_path, DRIVE, seed=2, cache_dir=cache) as drv:
        other = drv.run_all()
    assert not np.array_equal(other["speed_m_s"][: len(rect_run["speed_m_s"])][:5000],
                              rect_run["speed_m_s"][:5000])


@pytest.mark.parametrize("name", ["l_field.geojson", "u_field.shp"])
def test_l_shaped_and_non_convex_fields(name, cache):
    field = Field.from_file(os.path.join(DATA, name))
    path = plan_coverage(field, 12.0, headland_passes=1)
    with SumoDriver(path, DRIVE, seed=3, cache_dir=cache) as drv:
        r = drv.run_all()
    assert r["s_m"][-1] == pytest.approx(path.length_m)
    kinds = _kinds(path, r)
    sw = (kinds == "swath")
    # The driven swath ticks cover the area inside the headlands.
    driven = []
    for i in np.unique(r["segment_index"][sw]):
        m = r["segment_index"] == i
        driven.append(shapely.LineString(np.column_stack([r["x_m"][m], r["y_m"][m]])))
    covered = shapely.union_all([d.buffer(6.0, cap_style="flat") for d in driven])
    assert path.inner.intersection(covered).area / path.inner.area >= 0.98
    on = r["implement_on"]
    assert shapely.contains_xy(field.polygon, r["x_m"][on], r["y_m"][on]).all()


def test_network_cached_by_inputs(rect_path, cache):
    speeds = DRIVE.edge_speeds_m_s(rect_path.kinds())
    net = build_network(rect_path.segments, speeds, 20.0, cache_dir=cache)
    mtime = os.path.getmtime(net.net_file)
    again = build_network(rect_path.segments, speeds, 20.0, cache_dir=cache, netconvert="/bin/false")
    assert again.net_file == net.net_file and os.path.getmtime(net.net_file) == mtime
    other = build_network(rect_path.segments, [v + 0.1 for v in speeds], 20.0, cache_dir=cache)
    assert other.net_file != net.net_file


def test_netconvert_failure_is_one_clear_error(rect_path, tmp_path):
    speeds = DRIVE.edge_speeds_m_s(rect_path.kinds())
    with pytest.raises(VehicleError, match=r"netconvert /bin/false: failed \(exit 1\)"):
        build_network(rect_path.segments, speeds, 20.0, cache_dir=str(tmp_path), netconvert="/bin/false")
    assert not os.listdir(tmp_path)


def test_one_simulation_per_process(rect_path, cache):
    with SumoDriver(rect_path, DRIVE, cache_dir=cache):
        with pytest.raises(VehicleError, match="another SUMO simulation is open"):
            SumoDriver(rect_path, DRIVE, cache_dir=cache).open()
    with SumoDriver(rect_path, DRIVE, cache_dir=cache) as drv:  # closed cleanly: can start again
        assert drv.step().time_s == pytest.approx(0.05)


def test_driver_misuse(rect_path, cache):
    drv = SumoDriver(rect_path, DRIVE, cache_dir=cache)
    with pytest.raises(VehicleError, match="not open"):
        drv.step()
    with pytest.raises(VehicleError, match="step_s"):
        SumoDriver(rect_path, DRIVE, step_s=0.0, cache_dir=cache)


def test_unfinished_drive_is_an_error(rect_path, cache):
    with SumoDriver(rect_path, DRIVE, cache_dir=cache, max_time_s=30.0) as drv:
        with pytest.raises(VehicleError, match="did not finish .* within max_time_s=30 s"):
            drv.run_all()
    with SumoDriver(rect_path, DRIVE, step_s=0.5, cache_dir=cache, max_time_s=2.0) as drv:
        for _ in range(4):
            drv.step()
        with pytest.raises(VehicleError, match="max_time_s=2 s"):
            drv.step()
    with pytest.raises(VehicleError, match="max_time_s must be"):
        SumoDriver(rect_path, DRIVE, cache_dir=cache, max_time_s=-1.0)


def test_damaged_cache_entry_is_rebuilt(rect_path, tmp_path):
    speeds = DRIVE.edge_speeds_m_s(rect_path.kinds())
    net = build_network(rect_path.segments, speeds, 20.0, cache_dir=str(tmp_path))
    with open(net.net_file, "w") as f:
        f.write("<net><truncated")  # SUMO would crash the process on this
    again = build_network(rect_path.segments, speeds, 20.0, cache_dir=str(tmp_path))
    with open(again.net_file) as f:
        assert f.read().rstrip().endswith("</net>")


def test_slower_headland_speed(cache):
    path = plan_coverage(Field.rectangle(60.0, 100.0), 12.0, headland_passes=1)
    drive = DriveConfig(headland_speed_m_s=1.8)
    with SumoDriver(path, drive, seed=1, cache_dir=cache) as drv:
        r = drv.run_all()
    kinds = _kinds(path, r)
    front = np.array(path.kinds())[path.segment_at(r["s_m"] + drive.implement_offset_m)]
    on_headland = (kinds == "headland") & (front == "headland")
    assert on_headland.sum() > 100
    assert r["speed_m_s"][on_headland].max() <= 1.8 + 1e-9
    assert r["speed_m_s"][kinds == "swath"].max() > 2.3
