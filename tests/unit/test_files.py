"""common.files: regular files only, byte caps before parsing, zip members checked before inflating,
grid memory estimated before allocating. (Memory and time, through every reader: tests/integration.)"""

from __future__ import annotations

import os
import zipfile

import pytest

from vrsim.common import MapError, VehicleError, files


def test_regular_file_within_its_cap_is_read(tmp_path):
    p = tmp_path / "a.csv"
    p.write_bytes(b"x,y\n1,2\n")
    assert files.check_file(str(p)) == 8
    assert files.read_bytes(str(p), error=MapError) == b"x,y\n1,2\n"


@pytest.mark.parametrize("make, what", [
    (lambda p: os.mkfifo(p), "is a FIFO"),
    (lambda p: os.symlink("/dev/zero", p), "is a device"),
    (lambda p: os.mkdir(p), "is a folder"),
])
def test_fifo_device_and_folder_are_refused_without_blocking(tmp_path, make, what):
    p = str(tmp_path / "m.geojson")
    make(p)
    for call in (files.check_file, files.read_bytes):
        with pytest.raises(MapError, match=what) as err:
            call(p, error=MapError)
        assert str(err.value).startswith(p)


def test_missing_file_and_oversize_file_name_the_file_and_the_cap(tmp_path):
    with pytest.raises(VehicleError, match="no such file"):
        files.read_bytes(str(tmp_path / "none.geojson"), error=VehicleError)
    p = tmp_path / "big.csv"
    with open(p, "wb") as fh:
        fh.truncate(files.BYTE_CAPS["csv"] + 1)  # sparse: no disk used
    with pytest.raises(MapError, match=r"big.csv: 67,108,865 bytes is over the 64 MB cap for csv") as err:
        files.read_bytes(str(p), error=MapError)
    assert "set_byte_caps" in str(err.value)
    with pytest.raises(MapError, match="over the 4 bytes cap"):
        files.read_bytes(str(tmp_path / "big.csv"), error=MapError, limit=4)


def test_byte_caps_can_be_raised_but_not_invented():
    old = dict(files.BYTE_CAPS)
    try:
        files.set_byte_caps(csv=2 * files.GiB)
        assert files.cap_for("csv") == 2 * files.GiB
        with pytest.raises(files.VrsimError, match="unknown format 'docx'"):
            files.set_byte_caps(docx=1)
        with pytest.raises(files.VrsimError, match="positive"):
            files.set_byte_caps(csv=0)
    finally:
        files.BYTE_CAPS.clear()
        files.BYTE_CAPS.update(old)


def test_zip_members_are_checked_before_inflating(tmp_path):
    bomb = tmp_path / "bomb.zip"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("zones.shp", b"\0" * (4 * files.MiB))
    old = dict(files.BYTE_CAPS)
    try:
        files.set_byte_caps(shapefile=files.MiB)
        with pytest.raises(MapError, match=r"member zones.shp: 4,194,304 bytes is over the 1 MB cap"):
            files.open_zip(str(bomb), MapError)
    finally:
        files.BYTE_CAPS.update(old)
    with files.open_zip(str(bomb), MapError) as z:
        with pytest.raises(MapError, match="over the 10 bytes cap"):
            files.read_member(z, "zones.shp", str(bomb), MapError, limit=10)


def test_a_zip_listing_too_many_members_is_refused_from_its_end_record(tmp_path):
    many = tmp_path / "many.zip"
    with zipfile.ZipFile(many, "w") as z:
        for i in range(files.MAX_ZIP_MEMBERS + 1):
            z.writestr(f"f{i}.txt", b"")
    with pytest.raises(MapError, match="lists 10,001 members"):
        files.open_zip(str(many), MapError)
    (tmp_path / "not.zip").write_bytes(b"garbage")
    with pytest.raises(MapError, match="not a zip archive"):
        files.open_zip(str(tmp_path / "not.zip"), MapError)


def test_siblings_a_library_may_open_must_be_regular(tmp_path):
    tif = tmp_path / "rx.tif"
    tif.write_bytes(b"II*\0")
    (tmp_path / "rx.tfw").write_text("1\n0\n0\n-1\n0\n0\n")
    (tmp_path / "other.tif.aux.xml").write_text("")
    os.mkfifo(tmp_path / "other_fifo")
    for other in ("rx.tif.bak", "rx.zip", "rx_big.tif"):  # beside it, not parsed whole: type only, no size
        with open(tmp_path / other, "wb") as fh:
            fh.truncate(2 * files.GiB)
    os.mkfifo(tmp_path / "rx_other_fifo")
    files.check_siblings(str(tif), MapError)
    with open(tmp_path / "rx.tif.aux.xml", "wb") as fh:
        fh.truncate(files.BYTE_CAPS["xml"] + 1)
    with pytest.raises(MapError, match=r"rx.tif.aux.xml: 67,108,865 bytes is over the 64 MB cap for xml"):
        files.check_siblings(str(tif), MapError)
    os.unlink(tmp_path / "rx.tif.aux.xml")
    os.mkfifo(tmp_path / "rx.tif.aux.xml")
    with pytest.raises(MapError, match=r"rx.tif.aux.xml: is a FIFO"):
        files.check_siblings(str(tif), MapError)


def test_grid_memory_is_estimated_before_allocating(tmp_path):
    files.check_grid_memory(1000, 1000, 16, "small", MapError)
    with pytest.raises(MapError, match=r"huge: a grid of 100,000 rows x 100,000 columns "
                                       r"\(16 bytes per cell\) needs about 149"):
        files.check_grid_memory(100_000, 100_000, 16, "huge", MapError)
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       24684816 kB\nMemAvailable:   1048576 kB\n")
    assert files._available_memory_bytes(str(meminfo)) == files.GiB
    assert files._available_memory_bytes(str(tmp_path / "none")) is None
