"""common.files.written and staged: an output appears under its final name whole or not at all, and a
failure for lack of space or permission is one line naming the folder."""

import errno
import os

import pytest

from vrsim.common import MapError, VrsimError
from vrsim.common.written import staged, write_failure, written


def _names(folder) -> list[str]:
    return sorted(os.listdir(folder))


def test_a_file_appears_under_its_name_only_when_complete(tmp_path):
    path = tmp_path / "report.html"
    with written(str(path)) as temp:
        assert os.path.dirname(temp) == str(tmp_path) and temp.endswith(".html")
        with open(temp, "w") as fh:
            fh.write("whole")
        assert not path.exists()
    assert _names(tmp_path) == ["report.html"] and path.read_text() == "whole"


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("old")
    with pytest.raises(ZeroDivisionError), written(str(path)) as temp:
        with open(temp, "w") as fh:
            fh.write("half")
        with open(temp + "-journal", "w") as fh:  # what a library may make beside it
            fh.write("x")
        raise ZeroDivisionError  # a bug stays a bug
    assert _names(tmp_path) == ["t.csv"] and path.read_text() == "old"


def test_no_space_becomes_one_line_naming_the_folder(tmp_path):
    with pytest.raises(MapError) as err, written(str(tmp_path / "a.tif"), MapError) as temp:
        open(temp, "w").close()
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), temp)
    assert str(err.value) == (f"cannot write in {tmp_path}: no space left on the device (nothing incomplete "
                              "was left under a final name)")
    assert _names(tmp_path) == []


@pytest.mark.parametrize("exc, cause", [
    (RuntimeError("the plot worker: draw_maps x.png: OSError: [Errno 28] No space left on device"),
     "no space left on the device"),
    (VrsimError("taskdata: cannot write TLG00001.bin: Read-only file system"), "read-only file system"),
    (OSError(errno.EACCES, "Permission denied"), "permission denied"),
])
def test_causes_are_found_in_a_libraries_message(tmp_path, exc, cause):
    assert f": {cause} (" in str(write_failure(exc, str(tmp_path)))


def test_other_failures_in_a_writable_folder_are_not_taken_for_space(tmp_path):
    assert write_failure(ValueError("no such table: gpkg_contents"), str(tmp_path)) is None


def test_a_staged_set_moves_in_with_its_mark_last_and_keeps_other_files(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("kept")
    (out / "taskdata").mkdir()
    (out / "taskdata" / "README").write_text("kept too")
    moved = []
    real_replace = os.replace

    def spy(src, dst):
        moved.append(os.path.basename(dst))
        real_replace(src, dst)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(os, "replace", spy)
        with staged(str(out), last=("summary.json",)) as stage:
            for name in ("summary.json", "a.tif", "z.csv"):
                (tmp_path / stage / name).write_text(name)
            os.mkdir(os.path.join(stage, "taskdata"))
            (tmp_path / stage / "taskdata" / "TASKDATA.XML").write_text("xml")
    assert moved[-1] == "summary.json"
    assert _names(out) == ["a.tif", "mine.txt", "summary.json", "taskdata", "z.csv"]
    assert _names(out / "taskdata") == ["README", "TASKDATA.XML"]


def test_a_failed_set_changes_nothing_and_removes_the_folder_it_made(tmp_path):
    out = tmp_path / "new"
    with pytest.raises(KeyError), staged(str(out)) as stage:
        (tmp_path / stage / "a.tif").write_text("a")
        raise KeyError("bug")
    assert _names(tmp_path) == []


def test_a_folder_that_cannot_be_made_is_one_line(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(VrsimError, match="file/out: cannot create the folder"), \
            staged(str(tmp_path / "file" / "out")):
        pass


def test_files_a_writer_makes_beside_it_follow_it(tmp_path):
    with written(str(tmp_path / "rx.csv")) as temp:
        for ext in (".csv", ".prj"):
            (tmp_path / (os.path.splitext(temp)[0] + ext)).write_text(ext)
    assert _names(tmp_path) == ["rx.csv", "rx.prj"]


def test_what_c_code_prints_about_a_write_is_dropped_only_when_the_one_line_says_it(tmp_path, capfd):
    with written(str(tmp_path / "ok.tif")) as temp:
        open(temp, "w").close()
        os.write(2, b"a warning of a write that worked\n")
    with pytest.raises(VrsimError), written(str(tmp_path / "full.tif")) as temp:
        os.write(2, b"_tiffWriteProc: No space left on device.\n")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert capfd.readouterr().err == "a warning of a write that worked\n"
