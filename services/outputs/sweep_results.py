"""A sweep's result table, ``results.parquet`` and ``results.csv``, kept current as runs finish; and
the optional per-run output files of a sweep.

Both files are rewritten whole (to a temporary file, then renamed over the old one) at most once per
`flush_every_s` and at the end, so a reader or a ``--resume`` after a crash always finds a complete
table, at most that much behind. Columns: ``key, scenario, seed``, one per axis (its dotted key), the
run's numeric figures, then ``wall_s, status, error``; a failed or lost run's figures are null.

``status``: ``ok``; ``failed`` (the run itself failed, and would again: kept by ``--resume`` unless
``--retry-failed``); ``lost`` (the cluster dropped it: ``--resume`` runs it again).
"""

from __future__ import annotations

import csv
import os
import time

from vrsim.common import ScenarioError
from vrsim.common.written import write_failure, written
from vrsim.services.sim.sweep import ROW_FIRST, ROW_LAST

PARQUET = "results.parquet"
CSV = "results.csv"
# The errors that tables written before the `lost` status gave rows the cluster dropped: they are read
# as lost, so `--resume` runs them again.
_OLD_LOST_ERRORS = ("cancelled: the cluster dropped this task", "worker died while running this task")


def _columns(rows: list[dict]) -> list[str]:
    """The table's columns: identity first, status last, the rest in first-seen order."""
    middle = {}
    for row in rows:
        middle.update(dict.fromkeys(k for k in row if k not in ROW_FIRST and k not in ROW_LAST))
    return [*ROW_FIRST, *middle, *ROW_LAST]


def _read_rows(path: str) -> list[dict]:
    """The rows of a results.parquet (nulls as None)."""
    import pyarrow.parquet as pq

    try:
        return pq.read_table(path).to_pylist()
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"{path}: cannot read the results table: {exc}") from None


def _status(row: dict) -> str:
    """A row's status, a dropped task's of an older table `lost`."""
    if row.get("status") == "failed" and str(row.get("error")).startswith(_OLD_LOST_ERRORS):
        return "lost"
    return row.get("status")


def _write_parquet(rows: list[dict], path: str) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = _columns(rows)
    table = pa.table({name: pa.array([row.get(name) for row in rows]) for name in names})
    with written(path) as temp:
        pq.write_table(table, temp)


def _write_csv(rows: list[dict], path: str) -> None:
    """CSV with a header; floats as Python writes them (round-trip exact), nulls as empty fields."""
    with written(path) as temp, open(temp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=_columns(rows), restval="")
        writer.writeheader()
        writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in rows)


class ResultsTable:
    """The rows of a sweep in `out_dir`, written as they come.

    Parameters
    ----------
    out_dir : str
    resume : bool
        Keep the ok and failed rows of an existing results.parquet (their keys are `done`); its lost
        rows are dropped, to be run again. Without it, an existing table is an error rather than
        overwritten.
    retry_failed : bool
        On `resume`, drop the failed rows too.
    flush_every_s : float
        Rewrite the files at most this often while rows come in, s.
    """

    def __init__(self, out_dir: str, resume: bool = False, flush_every_s: float = 1.0,
                 retry_failed: bool = False):
        self.out_dir = out_dir
        self.parquet = os.path.join(out_dir, PARQUET)
        self.csv = os.path.join(out_dir, CSV)
        self.flush_every_s = flush_every_s
        self.rows: list[dict] = []
        _check_out_dir(out_dir)
        exists = os.path.isfile(self.parquet)
        if exists and not resume:
            raise ScenarioError(f"{self.parquet} exists: add --resume to go on with that sweep, or choose "
                                f"another --out")
        if exists:
            kept = ("ok",) if retry_failed else ("ok", "failed")
            self.rows = [row for row in _read_rows(self.parquet) if _status(row) in kept]
        self._flushed = time.monotonic()

    @property
    def done(self) -> set[str]:
        """Keys of the runs already in the table."""
        return {row["key"] for row in self.rows}

    def add(self, row: dict) -> None:
        self.rows.append(row)
        if time.monotonic() - self._flushed >= self.flush_every_s:
            self.flush()

    def flush(self) -> None:
        """Write both files now (and create `out_dir`: nothing is created before the first flush)."""
        try:
            os.makedirs(self.out_dir, exist_ok=True)
        except OSError as exc:
            raise write_failure(exc, os.path.abspath(self.out_dir), ScenarioError) or ScenarioError(
                f"{self.out_dir}: cannot create the folder ({exc.strerror})") from None
        if self.rows:
            _write_parquet(self.rows, self.parquet)
            _write_csv(self.rows, self.csv)
        self._flushed = time.monotonic()


def _check_out_dir(out_dir: str) -> None:
    """Refuse an `out_dir` that cannot be written before any run, not after the first: the nearest
    folder of it that exists is read-only, full or not writable (`write_failure`), or is a file."""
    near = os.path.abspath(out_dir)
    while not os.path.lexists(near) and os.path.dirname(near) != near:
        near = os.path.dirname(near)
    if not os.path.isdir(near):
        raise ScenarioError(f"{out_dir}: cannot create the folder: {near} is not a folder")
    # No write was tried yet: write_failure judges the folder as it is (read-only, full, no access).
    failure = write_failure(Exception(), near, ScenarioError)
    if failure is not None:
        raise failure


class RunOutputs:
    """``after`` hook of `services.sim.sweep.run_row` that writes a run's usual output files into
    ``<root>/runs/<key>/`` and adds ``outputs_wall_s`` to its figures (picklable: it runs on workers)."""

    def __init__(self, root: str):
        self.root = os.path.abspath(root)

    def __call__(self, spec, result) -> None:
        from vrsim.services.outputs.write import write_outputs

        t0 = time.perf_counter()
        write_outputs(result, os.path.join(self.root, "runs", spec.key))
        result.summary["outputs_wall_s"] = time.perf_counter() - t0
