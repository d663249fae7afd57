"""Outputs whole or absent, on a real full disk and a real read-only folder: a small tmpfs (mounted as
root; skipped where mount is refused) that `vrsim run`, `vrsim map convert` and a sweep's report do
not fit in, and a tmpfs remounted read-only. Each exits 2 with one line naming the folder and the
cause, and leaves nothing behind: no file under a final name, no temporary file."""

from __future__ import annotations

import contextlib
import os
import subprocess

import numpy as np
import pytest
from affine import Affine

from tests.conftest import VRSIM
from vrsim.maps import Grid, write_map

QUICK = """
name = "quick"
seed = 5
[field]
rectangle = { width_m = 72.0, length_m = 150.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "zones"
cell_size_m = 2.0
params = { n_zones = 4 }
[output]
plots = true
html = true
"""
TAIL = "(nothing incomplete was left under a final name)"


@contextlib.contextmanager
def tmpfs(folder, size: str, read_only: bool = False, inside: tuple[str, ...] = ()):
    """A tmpfs of ``size`` mounted on ``folder`` (made), holding the empty folders ``inside``; then
    remounted read-only if asked. Skips the test where mounting is refused (not root)."""
    folder = str(folder)
    os.makedirs(folder)
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", folder],
                       capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {p.stderr.strip() or 'mount refused'}")
    try:
        for name in inside:
            os.mkdir(os.path.join(folder, name))
        if read_only:
            subprocess.run(["mount", "-o", "remount,ro", folder], check=True)
        yield folder
    finally:  # lazily if busy: no test leaves a mount behind
        if subprocess.run(["umount", folder], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", folder], check=True)


def vrsim(*args):
    return subprocess.run([VRSIM, *map(str, args)], capture_output=True, text=True, timeout=300)


def everything_in(folder) -> list[str]:
    return sorted(os.path.relpath(os.path.join(root, name), folder)
                  for root, dirs, files in os.walk(folder) for name in dirs + files)


def refused(p: subprocess.CompletedProcess, command: str, folder: str, cause: str) -> None:
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    lines = [line for line in p.stderr.splitlines() if f"vrsim {command}: warning: " not in line]
    assert lines == [f"vrsim {command}: error: cannot write in {folder}: {cause} {TAIL}"]


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "q.toml"
    path.write_text(QUICK)
    return path


def test_run_to_a_full_disk_exits_2_and_leaves_nothing(tmp_path, scenario):
    with tmpfs(tmp_path / "full", "200k") as mount:
        out = os.path.join(mount, "out")
        refused(vrsim("run", scenario, "--quiet", "--out", out), "run", out, "no space left on the device")
        assert everything_in(mount) == []


@pytest.mark.parametrize("out", ["new", "there", "."])
def test_run_to_a_read_only_folder_exits_2(tmp_path, scenario, out):
    with tmpfs(tmp_path / "ro", "1m", read_only=True, inside=("there",)) as mount:
        folder = os.path.normpath(os.path.join(mount, out))
        refused(vrsim("run", scenario, "--quiet", "--out", folder), "run", folder, "read-only file system")
        assert everything_in(mount) == ["there"]


@pytest.fixture(scope="module")
def big_map(tmp_path_factory) -> str:
    """A 300 x 300 GeoTIFF of noise: every format of it is far over 200 KB."""
    rates = np.random.default_rng(1).uniform(80.0, 220.0, (300, 300))
    path = str(tmp_path_factory.mktemp("map") / "rx.tif")
    write_map(Grid(rates, Affine(2.0, 0, 500000.0, 0, -2.0, 5300600.0), "EPSG:32632"), path)
    return path


@pytest.mark.parametrize("name", ["rx.geojson", "rx.csv", "rx.tif", "rx.zip", "TASKDATA"])
def test_map_convert_to_a_full_disk_exits_2_and_leaves_nothing(tmp_path, big_map, name):
    with tmpfs(tmp_path / "full", "200k") as mount:
        p = vrsim("map", "convert", big_map, os.path.join(mount, name))
        refused(p, "map", mount, "no space left on the device")
        assert everything_in(mount) == []


def test_map_convert_into_an_existing_isoxml_folder_removes_only_what_it_added(tmp_path, big_map):
    with tmpfs(tmp_path / "full", "200k", inside=("TASKDATA",)) as mount:
        folder = os.path.join(mount, "TASKDATA")
        with open(os.path.join(folder, "GRD00001.BIN"), "wb") as fh:  # another export's grid
            fh.write(b"\0" * 4096)
        refused(vrsim("map", "convert", big_map, folder), "map", folder, "no space left on the device")
        assert everything_in(mount) == ["TASKDATA", os.path.join("TASKDATA", "GRD00001.BIN")]


def test_map_convert_to_a_read_only_folder_exits_2(tmp_path, big_map):
    with tmpfs(tmp_path / "ro", "1m", read_only=True) as mount:
        refused(vrsim("map", "convert", big_map, os.path.join(mount, "rx.geojson")), "map", mount,
                "read-only file system")


def test_evaluate_to_a_full_disk_exits_2_and_leaves_nothing(tmp_path, scenario):
    run = tmp_path / "run"
    p = vrsim("run", scenario, "--quiet", "--set", "output.plots=false", "--set", "output.html=false",
              "--out", run)
    assert p.returncode == 0, p.stderr
    with tmpfs(tmp_path / "full", "200k") as mount:
        out = os.path.join(mount, "evaluation")
        p = vrsim("evaluate", run / "taskdata", "--prescription", run / "prescription.tif", "--out", out)
        refused(p, "evaluate", out, "no space left on the device")
        assert everything_in(mount) == []
