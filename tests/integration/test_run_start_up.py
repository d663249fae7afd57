"""`vrsim run`'s start-up: no garbage collection while it imports and loads, what it made frozen
for the run, and the collector as it was once the command returns (the command runs in process for
the Python API's callers and the tests)."""

import gc
import os

from tests.conftest import ROOT
from vrsim.services.cli.main import main

QUICK = os.path.join(ROOT, "scenarios", "quick_rectangle.toml")


def test_run_freezes_start_up_and_leaves_the_collector_as_it_found_it(tmp_path, monkeypatch):
    import vrsim.services.sim.streamed as streamed

    seen = {}
    run_streamed = streamed.run_streamed

    def watched(*args, **kwargs):
        seen.update(enabled=gc.isenabled(), frozen=gc.get_freeze_count(), threshold=gc.get_threshold())
        return run_streamed(*args, **kwargs)

    monkeypatch.setattr(streamed, "run_streamed", watched)
    before = gc.get_threshold()
    gc.set_threshold(900, 11, 12)
    try:
        assert main(["run", QUICK, "--quiet", "--out", str(tmp_path / "out")]) == 0
        assert seen["enabled"] and seen["frozen"] > 10_000 and seen["threshold"][0] == 10_000
        assert gc.isenabled() and gc.get_freeze_count() == 0 and gc.get_threshold() == (900, 11, 12)
    finally:
        gc.set_threshold(*before)


def test_run_in_a_folder_holding_a_services_package_runs_vrsims_own_workers(tmp_path):
    """The run's worker processes (SUMO's drive, the pictures) import vrsim's own modules, not a
    ``services`` package that happens to sit in the folder the command runs in (``python -P``)."""
    import subprocess

    from tests.conftest import VRSIM

    decoy = tmp_path / "services"
    decoy.mkdir()
    (decoy / "__init__.py").write_text('raise SystemExit("a decoy services package was imported")\n')
    done = subprocess.run([VRSIM, "run", QUICK, "--quiet", "--out", str(tmp_path / "out")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "summary.json").is_file() and (tmp_path / "out" / "map.png").is_file()
