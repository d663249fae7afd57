"""Every module of the packages stays within the 500 lines the project set itself: one idea a module,
read in a sitting (a module that grows past it splits along its ideas, as controller/loop.py into
loop_matrix and loop_io)."""

import os

from tests.conftest import ROOT

PACKAGES = ("common", "controller", "maps", "vehicle", "services")
MAX_LINES = 500

def test_no_module_is_over_500_lines():
    long = {}
    for package in PACKAGES:
        for folder, _, names in os.walk(os.path.join(ROOT, package)):
            for name in names:
                if name.endswith(".py"):
                    path = os.path.join(folder, name)
                    with open(path, encoding="utf-8") as fh:
                        lines = sum(1 for _ in fh)
                    if lines > MAX_LINES:
                        long[os.path.relpath(path, ROOT)] = lines
    assert long == {}, long
