"""`common.arrow.arrow_array`: the Arrow array ``pyarrow.array`` makes, with no pandas loaded."""

import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest

from vrsim.common.arrow import arrow_array

CASES = [np.array([1.0, np.nan, -3.5, np.inf]), np.arange(19, dtype=np.int32), np.array([1, -2], np.int8),
         np.array([5, 7, 0], np.int16), np.array([], float),
         np.array(["2024-01-01T00:00:00.123", "2024-03-02"], "datetime64[ms]"),
         np.array(["kg/ha", "L/ha", "é"], dtype=object), ["0x1", "0x3f", ""]]


@pytest.mark.parametrize("values", CASES, ids=lambda v: str(np.asarray(v).dtype))
def test_the_same_array_as_pyarrow_makes(values):
    got, want = arrow_array(values), pa.array(values)
    assert got.type == want.type and got.null_count == want.null_count == 0
    if got.type == pa.float64():  # NaN is not equal to itself: compared as numpy compares NaN
        assert np.array_equal(got.to_numpy(), want.to_numpy(), equal_nan=True)
    else:
        assert got.equals(want) and got.to_pylist() == want.to_pylist()


def test_nan_as_null_as_from_pandas_makes_it():
    values = np.tile([1.0, np.nan, 3.5], 7)  # a validity bitmap over more than two bytes
    got, want = arrow_array(values, nan_is_null=True), pa.array(values, from_pandas=True)
    assert got.null_count == want.null_count == 7 and got.equals(want)


def test_no_pandas_is_loaded():
    code = ("import sys, numpy as np\nfrom vrsim.common.arrow import arrow_array\n"
            "arrow_array(np.arange(3.0), True), arrow_array(['a'])\n"
            "arrow_array(np.array([1], 'datetime64[s]'))\n"
            "print('pandas' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.stdout.split() == ["False"], done.stderr
