"""vrsim sweep end to end: real SUMO runs on a real Dask LocalCluster and on a separately started
scheduler and worker (all on 127.0.0.1), the real vrsim executable, real Parquet and CSV files."""

import csv
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time

import pytest

from tests.conftest import ROOT, VRSIM
from vrsim.services.outputs.sweep_results import _read_rows, _write_parquet

SCENARIO = """
name = "sweep_quick"
seed = 5
[field]
rectangle = { width_m = 72.0, length_m = 150.0, lat = 52.0, lon = 10.0 }
[map]
synthetic = "zones"
params = { n_zones = 4 }
[controller]
gains = "manual"
kp = 0.5
ki = 2.0
[output]
plots = false
html = false
"""

# Four runs: two controller gains x two headland settings, of which 30 passes cannot fit the field
# (a run that fails at run time, after the loader accepted it).
SWEEP = """
scenarios = ["q.toml"]
seeds = [1]
[axes]
"controller.kp" = [0.4, 0.8]
"field.headland_passes" = [1, 30]
[report]
pareto = ["within_10pct_area_pct", "transition_distance_m_mean"]
"""
TIMING = {"wall_time_s", "realtime_factor", "wall_s"}  # measure the machine, not the run


def vrsim(*args, timeout=300):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=timeout)


def sweep(folder, *args):
    p = vrsim("sweep", str(folder / "s.toml"), "--no-dashboard", "--json", "--quiet", *args)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def same_figures(a: dict, b: dict, ignore=()) -> dict:
    """The keys where two rows differ, timing (and `ignore`) left out."""
    keys = (set(a) | set(b)) - TIMING - set(ignore)
    return {k: (a.get(k), b.get(k)) for k in keys if a.get(k) != b.get(k)}


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """One sweep on an embedded LocalCluster of two workers: (folder, outcome, rows)."""
    folder = tmp_path_factory.mktemp("sweep")
    (folder / "q.toml").write_text(SCENARIO)
    (folder / "s.toml").write_text(SWEEP)
    outcome = sweep(folder, "--workers", "2", "--out", str(folder / "out"))
    return folder, outcome, _read_rows(str(folder / "out" / "results.parquet"))


def test_rows_equal_vrsim_run_of_the_same_combination(local, tmp_path):
    folder, outcome, rows = local
    assert (outcome["planned"], outcome["ran"], outcome["ok"], outcome["failed"], outcome["workers"]) == \
        (4, 4, 2, 2, 2)
    ok = [r for r in rows if r["status"] == "ok"]
    assert sorted(r["controller.kp"] for r in ok) == [0.4, 0.8]
    for row in ok:
        p = vrsim("run", str(folder / "q.toml"), "--set", f"controller.kp={row['controller.kp']}",
                  "--set", f"field.headland_passes={row['field.headland_passes']}", "--set", "seed=1",
                  "--json", "--quiet", "--out", str(tmp_path / row["key"]))
        assert p.returncode == 0, p.stderr
        single = json.loads(p.stdout)
        numbers = {k: v for k, v in single.items()
                   if (isinstance(v, (int, float)) or v is None) and k != "outputs_wall_s"}
        figures = {k: row[k] for k in numbers}
        assert same_figures(figures, numbers) == {}
        assert row["ticks"] > 1000 and row["error"] is None and row["wall_s"] > 0
    assert list(rows[0])[:5] == ["key", "scenario", "seed", "controller.kp", "field.headland_passes"]
    assert list(rows[0])[-3:] == ["wall_s", "status", "error"]


def test_a_failing_combination_is_a_failed_row_and_the_sweep_finishes(local):
    _, _, rows = local
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 2 and {r["field.headland_passes"] for r in failed} == {30}
    for row in failed:
        assert "q.toml: [field]" in row["error"] and "headland_passes=30" in row["error"]
        assert row["mae_kg_ha"] is None and row["scenario"] == "q.toml" and row["seed"] == 1


def test_csv_holds_the_same_rows_and_the_report_is_self_contained(local):
    folder, _, rows = local
    with open(folder / "out" / "results.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [r["key"] for r in table] == [r["key"] for r in rows]
    for text_row, row in zip(table, rows, strict=True):
        assert list(text_row) == list(row)
        for key, value in row.items():
            if isinstance(value, float):
                assert float(text_row[key]) == value
            else:
                assert text_row[key] == ("" if value is None else str(value))
    page = (folder / "out" / "report.html").read_text()
    refs = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert len(refs) >= 3 and all(ref.startswith("data:image/png;base64,") for ref in refs)
    assert "Pareto front" in page and "Against controller.kp" in page and "headland_passes=30" in page
    assert not (folder / "out" / "runs").exists()  # no per-run files unless asked


def test_resume_reruns_nothing(local):
    folder, _, rows = local
    outcome = sweep(folder, "--resume", "--out", str(folder / "out"))
    assert (outcome["planned"], outcome["skipped"], outcome["ran"], outcome["workers"]) == (4, 4, 0, 0)
    assert _read_rows(str(folder / "out" / "results.parquet")) == rows


def test_resume_runs_only_what_is_missing_and_run_outputs_are_written_when_asked(local):
    folder, _, rows = local
    out = folder / "partial"
    out.mkdir()
    missing = next(r for r in rows if r["status"] == "ok" and r["controller.kp"] == 0.8)
    _write_parquet([r for r in rows if r is not missing], str(out / "results.parquet"))
    outcome = sweep(folder, "--resume", "--out", str(out), "--workers", "1", "--run-outputs")
    assert (outcome["skipped"], outcome["ran"], outcome["ok"]) == (3, 1, 1)
    again = {r["key"]: r for r in _read_rows(str(out / "results.parquet"))}
    assert set(again) == {r["key"] for r in rows}
    for row in rows:
        assert same_figures(again[row["key"]], row, ignore={"outputs_wall_s"}) == {}
    assert again[missing["key"]]["outputs_wall_s"] > 0  # what writing its files took
    assert [p.name for p in (out / "runs").iterdir()] == [missing["key"]]
    saved = json.loads((out / "runs" / missing["key"] / "summary.json").read_text())
    assert saved["mae_kg_ha"] == missing["mae_kg_ha"] and saved["scenario_config"]["controller"]["kp"] == 0.8


def test_retry_failed_reruns_the_failed_runs_and_resume_alone_does_not(local):
    folder, _, rows = local
    out = folder / "retry"
    out.mkdir()
    _write_parquet(rows, str(out / "results.parquet"))
    failed = {r["key"] for r in rows if r["status"] == "failed"}
    outcome = sweep(folder, "--resume", "--retry-failed", "--out", str(out), "--workers", "1")
    assert (outcome["skipped"], outcome["ran"], outcome["failed"], outcome["lost"]) == (2, 2, 2, 0)
    again = _read_rows(str(out / "results.parquet"))
    assert [r["key"] for r in again[:2]] == [r["key"] for r in rows if r["key"] not in failed]
    assert {r["key"] for r in again[2:]} == failed  # run again, at the end of the table, not twice
    for row in again[2:]:
        assert row["status"] == "failed" and "headland_passes=30" in row["error"]


def test_an_existing_table_is_not_overwritten_without_resume(local):
    folder, _, _ = local
    p = vrsim("sweep", str(folder / "s.toml"), "--out", str(folder / "out"), "--no-dashboard")
    assert p.returncode == 2 and "results.parquet exists: add --resume" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_a_report_that_does_not_fit_exits_2_and_leaves_the_table_whole(local, tmp_path):
    from tests.integration.test_whole_outputs import refused, tmpfs

    folder, _, rows = local
    sizes = {name: -(-(folder / "out" / name).stat().st_size // 4096) * 4096  # whole pages of the tmpfs
             for name in ("results.parquet", "results.csv", "report.html")}
    room = 2 * (sizes["results.parquet"] + sizes["results.csv"])  # the table and its rewritten copy
    assert sizes["report.html"] > 2 * 4096  # the page does not fit in what is left
    with tmpfs(tmp_path / "full", f"{room // 1024 + 4}k", inside=("out",)) as mount:
        out = os.path.join(mount, "out")
        _write_parquet(rows, os.path.join(out, "results.parquet"))
        p = vrsim("sweep", str(folder / "s.toml"), "--no-dashboard", "--quiet", "--resume", "--out", out)
        refused(p, "sweep", out, "no space left on the device")
        names = set(os.listdir(out))  # the CSV too, unless the disk filled before it was written
        assert names in ({"results.parquet"}, {"results.parquet", "results.csv"})  # no report, no temporary
        assert _read_rows(os.path.join(out, "results.parquet")) == rows
        if "results.csv" in names:
            with open(os.path.join(out, "results.csv"), newline="") as fh:
                assert len(list(csv.DictReader(fh))) == len(rows)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_a_separately_started_scheduler_and_worker_give_the_same_table(local, tmp_path):
    folder, _, rows = local
    scheduler_file = tmp_path / "scheduler.json"
    env = dict(os.environ, PYTHONPATH=ROOT)
    scheduler = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
         "--no-dashboard", "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(scheduler_file)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=str(tmp_path))
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            assert scheduler.poll() is None, "the scheduler exited"
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        lonely = vrsim("sweep", str(folder / "s.toml"), "--scheduler", address, "--timeout", "2",
                       "--out", str(tmp_path / "lonely"))
        assert lonely.returncode == 2
        assert lonely.stderr == f"vrsim sweep: error: --scheduler {address}: no worker joined within 2 s\n"
        worker = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
             "--nworkers", "1", "--host", "127.0.0.1", "--no-dashboard", "--dashboard-address",
             "127.0.0.1:0"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=str(tmp_path))
        outcome = sweep(folder, "--scheduler", address, "--timeout", "60", "--out", str(tmp_path / "out"))
        assert (outcome["ran"], outcome["ok"], outcome["failed"], outcome["workers"]) == (4, 2, 2, 1)
    finally:
        for proc in (worker, scheduler):
            if proc is not None:
                _stop(proc)
    remote = {r["key"]: r for r in _read_rows(str(tmp_path / "out" / "results.parquet"))}
    assert set(remote) == {r["key"] for r in rows}
    for row in rows:
        assert same_figures(remote[row["key"]], row) == {}
        assert list(remote[row["key"]]) == list(row)


def test_a_scheduler_that_does_not_answer_exits_2(local):
    folder, _, _ = local
    p = vrsim("sweep", str(folder / "s.toml"), "--scheduler", f"tcp://127.0.0.1:{_free_port()}",
              "--timeout", "2", "--out", str(folder / "nowhere"), timeout=120)  # the deadline of a hang
    assert p.returncode == 2, p.stderr
    assert re.fullmatch(r"vrsim sweep: error: --scheduler tcp://127\.0\.0\.1:\d+: no answer within 2 s .*\n",
                        p.stderr)
    assert not (folder / "nowhere").exists()


@pytest.mark.parametrize("args, message", [
    (["run", "{q}", "--set", "controller.kpp=1", "--out", "{never}"],
     "q.toml: [controller] unknown key 'kpp'"),
    (["run", "{q}", "--set", "implement.width_m=-3", "--out", "{never}"],
     "q.toml: [implement] Implement: width_m must be"),
    (["run", "{q}", "--set", "nokey", "--out", "{never}"], "--set 'nokey': expected KEY=VALUE"),
    (["sweep", "{bad}", "--out", "{never}"],
     "bad.toml: scenario 'q.toml' with gnss.kind = 'galileo', seed = 1: "),
    (["sweep", "{s}", "--workers", "0", "--out", "{never}"], "--workers must be >= 1, got 0"),
    (["sweep", "{s}", "--resume"], "--resume needs --out DIR"),
])
def test_bad_input_is_one_line_and_exit_2(local, args, message):
    folder, _, _ = local
    (folder / "bad.toml").write_text('scenarios = ["q.toml"]\nseeds = [1]\n'
                                     '[axes]\n"gnss.kind" = ["galileo"]\n')
    paths = {"q": str(folder / "q.toml"), "bad": str(folder / "bad.toml"), "s": str(folder / "s.toml"),
             "never": str(folder / "never")}
    p = vrsim(*[a.format(**paths) for a in args])
    assert p.returncode == 2, p.stderr
    assert message in p.stderr and len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
    assert not (folder / "never").exists()


def test_a_worker_that_dies_gets_its_task_retried_once_then_lost(tmp_path):
    """Real worker processes killed mid-task (os._exit in the task): once -> the retry succeeds;
    every time -> a lost result after the retry; a task that raises runs twice, then fails (not
    lost); the other tasks finish either way."""
    from tests.integration.sweep_support import square_or_die
    from vrsim.services.batch.driver import open_client, run_tasks

    items = [(1, "", ""), (2, "once", str(tmp_path / "died-once")), (3, "always", str(tmp_path / "x")),
             (4, "", ""), (5, "raise", str(tmp_path / "attempts"))]
    done = {}
    with open_client(workers=2, dashboard=False) as client:
        run_tasks(client, items, square_or_die, key=lambda item: f"square-{item[0]}",
                  on_done=lambda item, *outcome: done.__setitem__(item[0], outcome))
    assert done[1] == (1, None, False) and done[2] == (4, None, False) and done[4] == (16, None, False)
    assert (tmp_path / "died-once").exists()
    result, error, lost = done[3]
    assert result is None and lost
    assert error.startswith("lost: worker died while running this task (2 attempts)")
    assert done[5] == (None, "ValueError: no square of 5 today", False)
    assert (tmp_path / "attempts").read_text() == "attempt\n" * 2
