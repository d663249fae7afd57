"""`vrsim run` in bounded memory (`services.sim.bounded`): its peak memory set by the map, not by the
ticks; the track in columnar and text files written as it goes; a field too big for the machine refused
at the start (real SUMO, the real executable)."""

import json
import os
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest

from tests.conftest import VRSIM

pytestmark = pytest.mark.integration

QUICK = os.path.join(os.path.dirname(__file__), "..", "..", "scenarios", "quick_rectangle.toml")
# Section control off: the coverage map's cells follow the sections' width, which the longer run narrows.
SAME_MAP = ["--set", "implement.section_control=off"]
# Ten times the ticks on the same field and map: a tenth of the width (ten times the swaths), a tenth
# of the product per revolution (the shaft turns as fast).
TEN_TIMES = ["--set", "implement.width_m=1.2", "--set", "implement.kg_per_rev=0.05"]


def _peak_rss_mb(args: list[str], out: str) -> tuple[float, dict]:
    """Peak resident memory of the largest process of ``vrsim run ARGS`` (its own or a worker's), MB,
    and its summary: measured in a fresh process whose only children they are."""
    probe = ("import json, resource, subprocess, sys\n"
             "done = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
             "assert done.returncode == 0, done.stderr\n"
             "print(json.dumps([resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,"
             " json.loads(done.stdout)]))\n")
    command = [VRSIM, "run", QUICK, "--json", "--quiet", "--out", out, *args]
    done = subprocess.run([sys.executable, "-c", probe, *command], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    peak_mb, summary = json.loads(done.stdout)
    return peak_mb, summary


@pytest.mark.slow
def test_a_run_ten_times_longer_on_the_same_map_peaks_less_than_10_pct_higher(tmp_path):
    short_mb, short = _peak_rss_mb(SAME_MAP, str(tmp_path / "short"))
    long_mb, long = _peak_rss_mb(SAME_MAP + TEN_TIMES, str(tmp_path / "long"))
    assert long["ticks"] >= 10 * short["ticks"]
    assert long["field_area_ha"] == short["field_area_ha"]
    assert long_mb < 1.10 * short_mb, (short_mb, long_mb)


def test_the_track_is_parquet_by_default_and_csv_on_request_with_the_same_columns(tmp_path):
    from vrsim.services.outputs.track import TRACK_COLUMNS

    out = tmp_path / "both"
    done = subprocess.run([VRSIM, "run", QUICK, "--quiet", "--out", str(out), "--set",
                           'output.track=["parquet", "csv"]', "--set", "output.plots=false", "--set",
                           "output.html=false"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "track.parquet, track.csv," in done.stdout
    text = pa_csv.read_csv(out / "track.csv", convert_options=pa_csv.ConvertOptions(
        column_types={"section_mask": pa.string()}))   # not the hexadecimal numbers pyarrow would read
    columnar = pq.read_table(out / "track.parquet")
    names = [name for name, _ in TRACK_COLUMNS]
    assert columnar.column_names == text.column_names == names
    summary = json.loads((out / "summary.json").read_text())
    assert columnar.num_rows == text.num_rows == summary["ticks"]
    for name in names:
        a, b = columnar.column(name).to_pylist(), text.column(name).to_pylist()
        if name == "section_mask":
            assert a == b
        else:   # text keeps each column's rounding: the same numbers, nulls where a value does not exist
            assert np.allclose(np.array(a, float), np.array(b, float), equal_nan=True, rtol=0, atol=1e-12), \
                name
    assert not [n for n in os.listdir(out) if n.startswith(".")]  # no temporary left

    only = tmp_path / "default"
    subprocess.run([VRSIM, "run", QUICK, "--quiet", "--out", str(only), "--set", "output.plots=false",
                    "--set", "output.html=false", "--set", "output.track=none"], check=True,
                   capture_output=True, timeout=300)
    assert not (only / "track.parquet").exists() and not (only / "track.csv").exists()


def test_a_field_too_big_for_the_machine_is_refused_at_the_start_with_the_estimate_and_the_limit(tmp_path):
    path = tmp_path / "vast.toml"
    # 8,100 ha (fields are capped at 10,000 ha) at 25 cm cells: over a billion cells, far more than any
    # machine's memory.
    path.write_text('name = "vast"\n[field]\nrectangle = { width_m = 9000.0, length_m = 9000.0, lat = 52.0, '
                    'lon = 10.0 }\n[map]\nsynthetic = "uniform"\ncell_size_m = 0.25\n'
                    '[implement]\nwidth_m = 24.0\n')
    done = subprocess.run([VRSIM, "run", str(path), "--quiet", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert "vast.toml: [field]" in lines[0] and "over a map of about 1,31" in lines[0]
    assert "needs about" in lines[0] and "GB of memory available" in lines[0]
    assert not (tmp_path / "out").exists()
