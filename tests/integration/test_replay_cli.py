"""`vrsim replay LOG`, the real executable: the John Deere sample exports replayed (figures,
replay.parquet, replay.png, replay_map.png, summary.json), a prescription as the target, sessions and a
time window chosen, and bad input refused with exit 2 and one line naming the file or option and the
value."""

import json
import os
import subprocess

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.conftest import VRSIM
from vrsim import maps
from vrsim.maps.pointlog import PointLog, read_point_log
from vrsim.maps.pointlog_write import write_points
from vrsim.services.sim.replay import EVENT_CLASSES

ASAPPLIED = os.path.join("data", "asapplied")
EACH_SECTION = os.path.join(ASAPPLIED, "jd-gen4-application-point-eachsection.zip")
ONE_HERTZ = os.path.join(ASAPPLIED, "jd-gen4-application-point-onehertz.zip")
COLUMNS = ["time_s", "session", "lon", "lat", "speed_m_s", "sections_on", "width_on_m", "target",
           "logged_applied", "simulated_applied", "event", "counts"]
FIGURES = ("mae_vs_log", "bias_vs_log", "rmse_vs_log", "r2_vs_log", "within_10pct_of_log_pct")


def vrsim(*args):
    return subprocess.run([VRSIM, "replay", *map(str, args)], capture_output=True, text=True, timeout=300)


def write_log(path, time_s, target=150.0):
    """A 12 m machine driving east at 2 m/s, one record per second of `time_s`, kg/ha, written with
    `maps.pointlog_write.write_points` (a GeoPackage)."""
    n = time_s.size
    timed = np.isfinite(time_s).all()
    log = PointLog(500000.0 + 2.0 * np.arange(n), np.full(n, 5760000.0), "EPSG:32632",
                   applied=150.0 + np.sin(np.arange(n)), target=np.full(n, target), unit="kg/ha",
                   time_s=time_s, start=np.datetime64("2026-05-01T10:00:00", "ms") if timed else None,
                   heading_deg=90.0, speed_m_s=2.0, width_m=12.0)
    return write_points(log, str(path))


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Small logs: two sessions of 100 s 120 s apart, 14 sessions of 30 s, no times, a time going
    back, no target."""
    folder = tmp_path_factory.mktemp("logs")
    going_back = np.arange(50.0)
    going_back[20] = 10.5
    made = {"two": np.concatenate((np.arange(100.0), 220.0 + np.arange(100.0))),
            "many": np.concatenate([200.0 * k + np.arange(30.0) for k in range(14)]),
            "no_time": np.full(50, np.nan), "going_back": going_back}
    out = {name: write_log(folder / f"{name}.gpkg", t) for name, t in made.items()}
    out["no_target"] = write_log(folder / "no_target.gpkg", np.arange(50.0), target=np.nan)
    return out


def run_json(*args) -> dict:
    p = vrsim(*args, "--json")
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)   # exactly one JSON object: anything else on stdout fails here


def test_each_section_export_replays_with_its_files(shared_dir, tmp_path):
    out = tmp_path / "replay"
    got = run_json(os.path.join(shared_dir, EACH_SECTION), "--out", out)
    print({k: got[k] for k in ("mae_vs_log", "target_mae_vs_log", "records", "sessions")})
    assert got["out_dir"] == str(out) and got["rate_unit"] == "gal/ac"
    assert got["records"] == 3902 and got["sessions"] == 1 and got["log_sessions"] == [0]
    assert got["target_from"] == "log"
    for prefix in ("", *(f"{name}_" for name in EVENT_CLASSES)):
        for key in (*FIGURES, *(f"target_{k}" for k in FIGURES), "compared_records"):
            assert prefix + key in got, prefix + key
    for key in ("standstill_records", "closed_records"):
        assert isinstance(got[key], int)
    assert 0 < got["mae_vs_log"] < 1.0 and got["compared_records"] > 3000
    assert sorted(os.listdir(out)) == ["replay.parquet", "replay.png", "replay_map.png", "summary.json"]
    assert json.loads((out / "summary.json").read_text()) == {k: v for k, v in got.items() if k != "out_dir"}
    for picture in ("replay.png", "replay_map.png"):
        assert (out / picture).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = pq.read_table(out / "replay.parquet")
    assert table.num_rows == 3902 and table.column_names == COLUMNS
    assert table.schema.metadata[b"rate_unit"] == b"gal/ac"
    assert table.schema.field("simulated_applied").metadata[b"unit"] == b"gal/ac"
    cols = {name: table[name].to_numpy(zero_copy_only=False) for name in COLUMNS}
    assert set(cols["event"]) <= set(EVENT_CLASSES) and cols["counts"].dtype == bool
    assert (np.diff(cols["time_s"]) > 0).all() and (cols["session"] == 0).all()
    assert np.isfinite(cols["lon"]).all() and (np.abs(cols["lat"]) < 90).all()
    # The figures are the table's: the twin's mean absolute error over the records that count.
    keep = cols["counts"] & np.isfinite(cols["simulated_applied"])
    mae = np.mean(np.abs(cols["simulated_applied"][keep] - cols["logged_applied"][keep]))
    assert keep.sum() == got["compared_records"] and mae == pytest.approx(got["mae_vs_log"], abs=1e-3)


def test_one_hertz_export_prints_the_figures_with_their_unit(shared_dir):
    p = vrsim(os.path.join(shared_dir, ONE_HERTZ))
    assert p.returncode == 0, p.stderr
    print(p.stdout)
    assert "780 records in 1 session" in p.stdout and "Rates in gal/ac" in p.stdout
    line = next(x for x in p.stdout.splitlines() if "Mean absolute error vs log" in x)
    assert line.count("gal/ac") == 2 and "target as prediction" in line
    for label in ("All records", "Pass starts", "Rate steps", "Section changes", "Steady"):
        assert label in p.stdout
    assert "Rate steps: no records" in p.stdout   # its target is constant
    # the transitions by event class, as vrsim run and vrsim evaluate count them: one pass here, too few
    # events for a figure
    line = next(x for x in p.stdout.splitlines() if x.strip().startswith("pass start"))
    assert "events     1 | 1" in line and "n/a | n/a" in line


def test_prescription_gives_the_target_at_each_record(shared_dir, tmp_path):
    """A two-zone map in WGS84 degrees (the log's records are in UTM metres) in gal/ac: each record's
    target is its zone's rate."""
    path = os.path.join(shared_dir, ONE_HERTZ)
    lon, lat = read_point_log(path).lonlat()
    bounds = (lon.min() - 1e-4, lat.min() - 1e-4, lon.max() + 1e-4, lat.max() + 1e-4)
    rates = np.full((20, 20), 8.0)
    rates[:, 10:] = 12.0
    cell = ((bounds[2] - bounds[0]) / 20, (bounds[3] - bounds[1]) / 20)
    rx = tmp_path / "rx.tif"
    maps.write_map(maps.grid_from_bounds(bounds, cell, "EPSG:4326", rates=rates, unit="gal/ac"), rx)
    got = run_json(path, "--prescription", rx, "--out", tmp_path / "out")
    assert got["target_from"] == str(rx) and got["off_prescription_records"] == 0
    table = pq.read_table(tmp_path / "out" / "replay.parquet")
    target = table["target"].to_numpy()
    assert set(np.unique(target)) == {8.0, 12.0} and min((target == 8.0).sum(), (target == 12.0).sum()) > 100
    # The twin follows the map's target: nearer it than the log (which applied 10 gal/ac) is.
    assert got["bias_vs_log"] < 0 and got["rate_step_compared_records"] > 0


def test_sessions_and_time_window_choose_the_records(logs, tmp_path):
    got = run_json(logs["two"], "--session", 1, "--out", tmp_path / "one")
    assert got["sessions"] == 1 and got["records"] == 100 and got["log_sessions"] == [1]
    table = pq.read_table(tmp_path / "one" / "replay.parquet")
    assert (table["session"].to_numpy() == 1).all() and table["time_s"].to_numpy()[0] == 220.0
    got = run_json(logs["two"], "--start-s", 50, "--end-s", 250)
    assert got["sessions"] == 2 and got["records"] == 50 + 31 and got["log_sessions"] == [0, 1]
    p = vrsim(logs["many"], "--out", tmp_path / "many")
    assert p.returncode == 0, p.stderr
    assert "420 records in 14 sessions (the log's 0-13)" in p.stdout
    assert (tmp_path / "many" / "replay.png").stat().st_size > 10_000


@pytest.mark.parametrize("case", ["no_time", "going_back", "session", "missing", "no_target", "window",
                                  "machine"])
def test_bad_input_exits_2_with_one_line(case, logs, shared_dir, tmp_path):
    each = os.path.join(shared_dir, EACH_SECTION)
    bad_machine = tmp_path / "machine_fit.toml"
    bad_machine.write_text("[response]\nnope = 1\n")
    args, needles = {
        "no_time": ((logs["no_time"],), ["no_time.gpkg", "record 0", "time is missing"]),
        "going_back": ((logs["going_back"],), ["going_back.gpkg", "record 20", "10.500 s", "time order"]),
        "session": ((each, "--session", 5), ["--session 5", "eachsection.zip", "1 session(s)"]),
        "missing": ((tmp_path / "nope.zip",), ["nope.zip", "no such file"]),
        "no_target": ((logs["no_target"],), ["no_target.gpkg", "target rate", "--prescription"]),
        "window": ((each, "--start-s", 900), ["--start-s 900", "eachsection.zip", "no record"]),
        "machine": ((logs["two"], "--machine", bad_machine), ["[response]", "'nope'"]),
    }[case]
    p = vrsim(*args, "--out", tmp_path / "out")
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    for needle in needles:
        assert needle in p.stderr, (needle, p.stderr)
    assert not (tmp_path / "out").exists()


def test_a_log_without_a_target_attribute_replays_on_a_prescription(logs, tmp_path):
    """The target comes from the map: a log that never had a target column is read without one."""
    from pyogrio.raw import read, write

    meta, _, geometry, columns = read(logs["two"])
    keep = [i for i, name in enumerate(meta["fields"]) if name != "target"]
    bare = tmp_path / "bare.gpkg"
    write(str(bare), geometry, [columns[i] for i in keep], [meta["fields"][i] for i in keep],
          geometry_type="Point", crs=meta["crs"], driver="GPKG")
    p = vrsim(bare)
    assert p.returncode == 2 and "target" in p.stderr and "Traceback" not in p.stderr
    x0, y0 = 500000.0, 5760000.0
    rx = tmp_path / "rx.tif"
    maps.write_map(maps.grid_from_bounds((x0 - 50, y0 - 50, x0 + 450, y0 + 50), 10.0, "EPSG:32632",
                                         rates=np.full((10, 50), 140.0), unit="kg/ha"), rx)
    got = run_json(bare, "--prescription", rx)
    assert got["target_from"] == str(rx) and got["compared_records"] > 150


def test_vrsims_own_timelog_replays_with_its_scenario(tmp_path):
    """A TASKDATA's TimeLog (the one `vrsim run` writes, as a task controller would: positions, the
    condensed work states of the sections, DDI 6 and 7) is a drive: its sections and rates replay."""
    sprayer = os.path.join(os.path.dirname(__file__), "..", "..", "scenarios", "sprayer.toml")
    run = subprocess.run([VRSIM, "run", sprayer, "--quiet", "--out", str(tmp_path / "run"), "--set",
                          "output.plots=false", "--set", "output.html=false"], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    got = run_json(tmp_path / "run" / "taskdata", "--scenario", sprayer, "--out", tmp_path / "replay")
    assert got["rate_unit"] == "kg/ha" and got["sessions"] == 1
    assert got["compared_records"] > 1000 and got["closed_records"] > 0   # the headland turns
    assert got["pass_start_compared_records"] > 0 and got["rate_step_compared_records"] > 0
    assert got["within_10pct_of_log_pct"] > 80
    table = pq.read_table(tmp_path / "replay" / "replay.parquet")
    assert table["sections_on"].to_numpy().max() == 6   # the scenario's six sections, from the TimeLog
