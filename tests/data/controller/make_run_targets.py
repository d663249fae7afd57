"""Regenerate run_targets.npz in this folder (run from the repo root):

    PYTHONPATH=. .venv/bin/python tests/data/controller/make_run_targets.py

The per-loop metering-shaft targets [rpm] of the first `TICKS` control periods of the built-in default
scenario with a twin-disc spinner (``spinner``: 2 loops) and with a drive per section
(``section_drives``: 6 loops), as the run hands them to its loops: the tractor starts at rest, the
sections open and the rates change across zone edges. `tests/unit/test_controller_multiloop.py` runs
the loops on them.
"""

import os

import numpy as np

from vrsim.controller.loop import ClosedLoop
from vrsim.services.sim import run as run_field
from vrsim.services.sim import scenario

HERE = os.path.dirname(os.path.abspath(__file__))
TICKS = 1200
IMPLEMENTS = {"spinner": {"kind": "spinner", "sections": 2, "spread_width_m": 24.0},
              "section_drives": {"kind": "section_drives"}}


def run_targets(implement: dict) -> np.ndarray:
    """The targets the run's loop gets in its first `TICKS` periods, shape (TICKS, loops)."""
    seen = []
    run = ClosedLoop.run

    def record(self, targets_rpm, *args, **kw):
        seen.append(np.array(targets_rpm))
        return run(self, targets_rpm, *args, **kw)

    ClosedLoop.run = record
    try:
        run_field(scenario.with_changes(scenario.load("default"), implement=implement))
    finally:
        ClosedLoop.run = run
    return np.concatenate(seen)[:TICKS]


if __name__ == "__main__":
    np.savez_compressed(os.path.join(HERE, "run_targets.npz"),
                        **{name: run_targets(implement) for name, implement in IMPLEMENTS.items()})
