"""Hostile files through the real readers, in a separate process whose peak memory is measured: a FIFO,
a link to /dev/zero and an oversize (sparse) file under every map extension, zip bombs, FIFO or device
parts of ISOXML and GeoTIFF, and fields of 1e9 m. Each is refused with a `VrsimError` naming the file
within seconds, and the process's peak resident memory stays under 500 MB above its baseline."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile

import pytest

from tests.conftest import ROOT, VRSIM
from vrsim.common import files

EXTENSIONS = (".geojson", ".csv", ".xml", ".zip", ".shp", ".tif")
MAX_SECONDS = 5.0
MAX_GROWTH_KB = 500 * 1024


def zip_bomb(path: str, member: str, size: int, also: dict | None = None) -> None:
    """A real deflate bomb: ``size`` zero bytes compressed to about size / 1000."""
    chunk = b"\0" * files.MiB
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        with z.open(member, "w", force_zip64=size >= 0xFFFFFFFF) as fh:
            for _ in range(size // files.MiB):
                fh.write(chunk)
        for name, data in (also or {}).items():
            z.writestr(name, data)


def write_boundary(path: str, ring: list, crs: str) -> None:
    with open(path, "w") as fh:
        json.dump({"type": "Feature", "crs": {"type": "name", "properties": {"name": crs}},
                   "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring]}}, fh)


def hostile_cases(folder: str) -> list:
    from vrsim import maps

    cases = []
    for ext in EXTENSIONS:
        zero, fifo, big = (os.path.join(folder, f"{name}{ext}") for name in ("zero", "fifo", "big"))
        os.symlink("/dev/zero", zero)
        os.mkfifo(fifo)
        with open(big, "wb") as fh:
            fh.truncate(files.BYTE_CAPS[files._kind_of(big)] + 1)  # sparse: no disk used
        cases += [(f"map /dev/zero as {ext}", "map", zero), (f"map FIFO as {ext}", "map", fifo),
                  (f"map oversize {ext}", "map", big)]
    bomb_shp, bomb_xml = os.path.join(folder, "bomb_shp.zip"), os.path.join(folder, "bomb_xml.zip")
    zip_bomb(bomb_shp, "zones.shp", files.BYTE_CAPS["shapefile"] + files.MiB, {"zones.dbf": b""})
    zip_bomb(bomb_xml, "TASKDATA.XML", files.BYTE_CAPS["xml"] + files.MiB)
    cases += [("map zip bomb (shapefile)", "map", bomb_shp), ("map zip bomb (ISOXML)", "map", bomb_xml)]
    iso_fifo = os.path.join(folder, "iso_fifo")
    os.mkdir(iso_fifo)
    os.mkfifo(os.path.join(iso_fifo, "TASKDATA.XML"))
    iso_zero = os.path.join(folder, "iso_zero")
    os.mkdir(iso_zero)
    grid = maps.read_map(os.path.join(ROOT, "tests", "data", "maps", "rx_utm32.tif"), unit="kg/ha")
    maps.write_map(grid, os.path.join(iso_zero, "TASKDATA.XML"))
    os.unlink(os.path.join(iso_zero, "GRD00001.BIN"))
    os.symlink("/dev/zero", os.path.join(iso_zero, "GRD00001.BIN"))
    sidecar = os.path.join(folder, "sidecar")
    os.mkdir(sidecar)
    shutil.copy(os.path.join(ROOT, "tests", "data", "maps", "rx_utm32.tif"), os.path.join(sidecar, "rx.tif"))
    os.mkfifo(os.path.join(sidecar, "rx.tif.aux.xml"))
    cases += [("ISOXML folder, TASKDATA.XML a FIFO", "map", iso_fifo),
              ("ISOXML folder, grid binary /dev/zero", "map", iso_zero),
              ("GeoTIFF with a FIFO .aux.xml beside it", "map", os.path.join(sidecar, "rx.tif"))]
    huge, wide = os.path.join(folder, "huge_field.geojson"), os.path.join(folder, "wide_field.geojson")
    utm_ring = [[5e5, 0.0], [5e5 + 1e9, 0.0], [5e5 + 1e9, 1e9], [5e5, 1e9], [5e5, 0.0]]
    write_boundary(huge, utm_ring, "EPSG:32632")
    write_boundary(wide, [[5.0, 45.0], [15.0, 45.0], [15.0, 55.0], [5.0, 55.0], [5.0, 45.0]], "EPSG:4326")
    cases += [("field /dev/zero as .geojson", "field", os.path.join(folder, "zero.geojson")),
              ("field FIFO as .shp", "field", os.path.join(folder, "fifo.shp")),
              ("field /dev/zero as .zip", "field", os.path.join(folder, "zero.zip")),
              ("field zip bomb", "field", bomb_shp),
              ("field 1e9 m x 1e9 m from a file", "field", huge),
              ("field 10 x 10 degrees from a file", "field", wide),
              ("field rectangle 1e9 m x 1e9 m", "rectangle", "1e9x1e9")]
    return cases


def test_hostile_files_are_refused_fast_with_bounded_memory(tmp_path):
    cases = hostile_cases(str(tmp_path))
    spec = tmp_path / "cases.json"
    spec.write_text(json.dumps(cases))
    done = subprocess.run([sys.executable, "-m", "tests.integration.bounded_probe", str(spec)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert done.returncode == 0, (done.stderr[-2000:], lines[-2:])
    results = {r["label"]: r for r in lines if "label" in r}
    assert len(results) == len(cases)
    for label, kind, path in cases:
        r = results[label]
        assert r["error"] in ("MapError", "VehicleError"), (label, r)
        assert r["seconds"] < MAX_SECONDS, (label, r)
        assert "\x00" not in r["message"], label
        if kind != "rectangle":
            assert os.path.basename(path) in r["message"], (label, r["message"])
    memory = lines[-1]
    growth_kb = memory["peak_kb"] - memory["baseline_kb"]
    assert growth_kb < MAX_GROWTH_KB, f"peak resident memory grew by {growth_kb / 1024:.0f} MB"


@pytest.mark.parametrize("field, map_file, expect", [
    ("rectangle = { width_m = 1e9, length_m = 1e9, lat = 52.1, lon = 11.6 }", None, "width_m = 1e+09 m"),
    ("rectangle = { width_m = 36.0, length_m = 60.0, lat = 52.1, lon = 11.6 }", "fifo.csv", "is a FIFO"),
])
def test_vrsim_run_refuses_a_huge_field_or_a_fifo_map_at_once(tmp_path, field, map_file, expect):
    if map_file:
        os.mkfifo(tmp_path / map_file)
    map_table = f'file = "{map_file}"' if map_file else 'synthetic = "uniform"'
    scenario = tmp_path / "s.toml"
    scenario.write_text(f'name = "hostile"\n[field]\n{field}\n[map]\n{map_table}\n'
                        "[implement]\nwidth_m = 12.0\n")
    done = subprocess.run([VRSIM, "run", str(scenario), "--out", str(tmp_path / "out")], capture_output=True,
                          text=True, timeout=60)  # refused before anything is built: a hang times out
    assert done.returncode == 2, done.stderr
    assert expect in done.stderr and "s.toml" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
