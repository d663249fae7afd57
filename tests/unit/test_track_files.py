"""The track files written in a thread (`services.outputs.track.TrackFiles`): the same files as the
parts give, whatever the thread's pace; a write that fails there is raised in the run's thread and
leaves nothing behind."""

import os

import numpy as np
import pyarrow.csv as pa_csv
import pytest

from vrsim.services.outputs.track import _ROW_KEYS, BACKLOG_PARTS, TrackFiles
from vrsim.vehicle import Field

FIELD = Field.rectangle(72.0, 150.0)


def rows(first: int, ticks: int) -> dict:
    t = np.arange(first, first + ticks, dtype=float)
    out = {k: t * 0.1 for k in _ROW_KEYS}
    out.update(x_m=10.0 + t % 50, y_m=20.0 + t % 70, implement_on=(t % 3 > 0),
               sections_on=np.tile(t[:, None] % 2 > 0, (1, 4)))
    return out


def test_parts_written_in_the_thread_are_the_rows_in_order(tmp_path):
    files = TrackFiles(FIELD, str(tmp_path), ["csv"])
    parts = [rows(i * 100, 100) for i in range(3 * BACKLOG_PARTS)]
    for part in parts:
        files(part)
        for v in part.values():   # the run's own arrays change after the call: the files do not
            v[...] = 0
    assert len(files._pending) <= BACKLOG_PARTS
    paths = files.finish()
    table = pa_csv.read_csv(paths["track.csv"])
    assert table.column("time_s").to_pylist() == pytest.approx(np.arange(600) * 0.1)
    assert os.listdir(tmp_path) == ["track.csv"]


def test_a_write_that_fails_in_the_thread_is_raised_and_leaves_nothing(tmp_path):
    out = tmp_path / "out"
    files = TrackFiles(FIELD, str(out), ["parquet", "csv"])
    os.rmdir(files.partial)   # the writers cannot open their files
    files(rows(0, 10))
    with pytest.raises(FileNotFoundError):
        files.finish()
    assert not out.exists()


def test_a_killed_runs_partial_track_is_removed_at_the_next_start(tmp_path):
    dead = subprocess_pid_that_ended()
    live = f".track-partial-{os.getpid()}-x"
    for name in (f".track-partial-{dead}-abcd1234", ".track-partial-old12345", live):
        (tmp_path / name).mkdir()
        (tmp_path / name / "track.csv").write_text("half a track")
    with pytest.warns(UserWarning, match="the unfinished track of a run that was killed"):
        files = TrackFiles(FIELD, str(tmp_path), ["csv"])
    left = sorted(n for n in os.listdir(tmp_path) if n.startswith(".track-partial-"))
    assert live in left and len(left) == 2  # a live run's own, and this one's
    files.abort()
    assert sorted(os.listdir(tmp_path)) == [live]


def subprocess_pid_that_ended() -> int:
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                       text=True)
    return int(p.stdout)
