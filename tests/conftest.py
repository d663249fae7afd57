"""Markers by folder: tests/unit -> unit, tests/integration -> integration, tests/accuracy -> accuracy."""

import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(ROOT), "shared")
VRSIM = os.path.join(os.path.dirname(sys.executable), "vrsim")


def pytest_collection_modifyitems(config, items):
    for item in items:
        parts = item.path.relative_to(ROOT).parts
        if len(parts) > 1 and parts[1] in ("unit", "integration", "accuracy"):
            item.add_marker(getattr(pytest.mark, parts[1]))


@pytest.fixture
def shared_dir():
    """../shared beside the checkout (the seed paper and real ISOXML files)."""
    if not os.path.isdir(SHARED):
        pytest.fail(f"{SHARED} is missing: the tests need ../shared beside the checkout")
    return SHARED
