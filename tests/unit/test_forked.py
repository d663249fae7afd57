"""`common.forked.Forked`: a function of this process's data in a forked child."""

import os
import signal
import time

import numpy as np
import pytest

from vrsim.common import MapError
from vrsim.common.forked import Forked

pytestmark = pytest.mark.unit


def _total(a, scale):
    return float(a.sum() * scale), os.getpid()


def _refuse(name):
    raise MapError(f"{name}: no such map")


def _sleep():
    time.sleep(60)


def test_the_child_computes_on_inherited_data_and_returns_the_value():
    data = np.arange(1_000_000, dtype=float)
    total, pid = Forked(_total, data, 2.0).result()
    assert total == 2.0 * data.sum() and pid != os.getpid()


def test_the_childs_exception_is_raised_in_the_parent():
    with pytest.raises(MapError, match="x.tif: no such map"):
        Forked(_refuse, "x.tif").result()


def test_a_killed_child_is_a_clear_error_and_cancel_reaps_it():
    job = Forked(_sleep)
    os.kill(job._proc.pid, signal.SIGKILL)
    with pytest.raises(RuntimeError, match=r"forked _sleep ended without a result \(exit code -9\)"):
        job.result()
    with Forked(_sleep) as job:
        pid = job._proc.pid
    assert not job._proc.is_alive()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
