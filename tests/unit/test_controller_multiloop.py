"""n loops of one plant on a real run's targets: the numbers of `ClosedLoop`'s shared-plant path.

A drive per section (6 loops), a spinner's two sides and sweeps' variants run their loops through
`ClosedLoop._shared_ticks`. On the targets the default field's run hands its loops
(`tests/data/controller/run_targets.npz`), every PID kind and form gives, bit for bit, the numbers
recorded from the path it replaced (an einsum per tick for the PID outputs), and its two ways of
computing the PID outputs (Python floats for a few loops, arrays for many) give the same numbers.

The product's rounding is the BLAS kernel's, which depends on the processor: the numbers are
recorded per OpenBLAS core (`DIGESTS`; ``python -m tests.unit.test_controller_multiloop`` prints the
running core's, and ``OPENBLAS_CORETYPE=Haswell`` selects another core where the processor has it).
"""

import ctypes
import glob
import hashlib
import os
from dataclasses import replace

import numpy as np
import pytest

from vrsim.controller import ControllerConfig, PlantParams, build_loop, build_variant_loops
from vrsim.controller import loop as loop_module

TARGETS = os.path.join(os.path.dirname(__file__), os.pardir, "data", "controller", "run_targets.npz")
P = PlantParams()
WEAK = replace(P, current_max_a=0.8, shaft_rpm_max=195.0)    # saturates both ways at 1.3 x the targets
CASES = [f"{run}-{kind}-{form}" for run in ("spinner", "section_drives")
         for kind in ("P", "PI", "PID", "variants") for form in ("incremental", "positional")]

# sha256 (first 16 hex digits) of each case's outputs and final state, recorded before the shared-plant
# path was rewritten, per OpenBLAS core.
DIGESTS = {
    "SkylakeX": {
        "spinner-P-incremental": "049e495ed4d83d02",
        "spinner-P-positional": "2943af6886f23582",
        "spinner-PI-incremental": "f9b98ca8387d99c1",
        "spinner-PI-positional": "83e817d043974d8d",
        "spinner-PID-incremental": "8a39d474cbf9020a",
        "spinner-PID-positional": "7e76a0b45de62979",
        "spinner-variants-incremental": "b836af4b2b903d87",
        "spinner-variants-positional": "7b4a40251b1d91ab",
        "section_drives-P-incremental": "ec62edfda6e46f9b",
        "section_drives-P-positional": "cc7980d31b1e3d95",
        "section_drives-PI-incremental": "cbf72b179e15d758",
        "section_drives-PI-positional": "aeb8f594748d6deb",
        "section_drives-PID-incremental": "349a11efa9cddb10",
        "section_drives-PID-positional": "5770b6109242c276",
        "section_drives-variants-incremental": "ba817bba1850999b",
        "section_drives-variants-positional": "4607413a3aa8c236",
    },
    "Haswell": {
        "spinner-P-incremental": "65a73553847fa11d",
        "spinner-P-positional": "9a123250df6f8bf4",
        "spinner-PI-incremental": "7df182279d6c315d",
        "spinner-PI-positional": "f5d8f71432293af5",
        "spinner-PID-incremental": "817009432d7220aa",
        "spinner-PID-positional": "2169dccc8f182fe6",
        "spinner-variants-incremental": "a5dde82c195aa335",
        "spinner-variants-positional": "dbcc0ddcdadeca85",
        "section_drives-P-incremental": "ff671cd073f30915",
        "section_drives-P-positional": "b62dbd1916e52c13",
        "section_drives-PI-incremental": "65da70f84d0b6daa",
        "section_drives-PI-positional": "165f039aa048b222",
        "section_drives-PID-incremental": "a91c44271ea5d6cd",
        "section_drives-PID-positional": "7ccdb7e43046dfd7",
        "section_drives-variants-incremental": "e38547cbe1f5cc3a",
        "section_drives-variants-positional": "f40247da70898d9b",
    },
    "Sandybridge": {
        "spinner-P-incremental": "3fc183c263f44e3f",
        "spinner-P-positional": "53558f92d5fec6e6",
        "spinner-PI-incremental": "e30c57db314d0de5",
        "spinner-PI-positional": "e59ca916fe713ca9",
        "spinner-PID-incremental": "9c4aff4cc0b8a082",
        "spinner-PID-positional": "014ba7ef4dd30dcf",
        "spinner-variants-incremental": "ab44f752ec7053da",
        "spinner-variants-positional": "36c622e5e2fdb5a5",
        "section_drives-P-incremental": "7d73b422b30a3e12",
        "section_drives-P-positional": "ef6ed521beff5c08",
        "section_drives-PI-incremental": "f69200fd31ef9603",
        "section_drives-PI-positional": "93b8e5940178ed40",
        "section_drives-PID-incremental": "9faa27333b6852a9",
        "section_drives-PID-positional": "2002b0b93d837aec",
        "section_drives-variants-incremental": "d4c313aef8b2d56c",
        "section_drives-variants-positional": "02b6627a4853ae3e",
    },
}


def _loop(kind: str, form: str, n: int):
    """The case's loop of n loops: a kind's paper gains as a run builds it, or n variants of the PID
    with their own gains and the derivative on the measurement, as a sweep batches them."""
    if kind != "variants":
        return build_loop(P, ControllerConfig(kind=kind, form=form, gains="paper"), n=n)
    cfgs = [ControllerConfig(kind="PID", form=form, gains="manual", kp=0.1 + 1.5 * f, ki=5.0 - 3.5 * f,
                             kd=0.01 * f, derivative_on_measurement=True) for f in np.linspace(0.0, 1.0, n)]
    (_, loop), = build_variant_loops(WEAK, cfgs)
    return loop


def _outputs(case: str) -> np.ndarray:
    """The case's outputs over the run's targets, run as two calls (the second carries on from the
    first), and its final state, as one flat array."""
    run, kind, form = case.split("-")
    targets = np.load(TARGETS)[run]
    loop = _loop(kind, form, targets.shape[1])
    if kind == "variants":     # one target row for all: each variant on the run's first loop
        targets = np.broadcast_to(1.3 * targets[:, :1], targets.shape)
    outs = [loop.run(targets[:7]), loop.run(targets[7:])]
    names = ("shaft_rpm", "shaft_rev", "current_a", "measured_rpm")
    parts = [getattr(o, name) for o in outs for name in names]
    return np.concatenate([p.ravel() for p in parts] + [np.ravel(loop.state)])


def _digest(case: str) -> str:
    return hashlib.sha256(np.ascontiguousarray(_outputs(case)).tobytes()).hexdigest()[:16]


def _openblas_core() -> str | None:
    """The core numpy's bundled OpenBLAS runs with (None where it cannot be asked)."""
    for path in glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs", "*openblas*")):
        corename = getattr(ctypes.CDLL(path), "scipy_openblas_get_corename64_", None)
        if corename is not None:
            corename.restype = ctypes.c_char_p
            return corename().decode()
    return None


def test_the_cases_saturate_both_ways_and_clamp():
    """The cases exercise what the numbers pin down: both current limits, the positional form held."""
    for case in ("section_drives-variants-positional", "spinner-variants-positional"):
        current = np.load(TARGETS)[case.split("-")[0]]
        loop = _loop("variants", case.split("-")[2], current.shape[1])
        current = loop.run(np.broadcast_to(1.3 * current[:, :1], current.shape)).current_a
        assert current.min() == WEAK.current_min_a and current.max() == WEAK.current_max_a, case


@pytest.mark.parametrize("case", CASES)
def test_shared_plant_loops_give_the_recorded_numbers_bit_for_bit(case):
    core = _openblas_core()
    if core not in DIGESTS:
        pytest.skip(f"no numbers recorded for OpenBLAS core {core}")
    assert _digest(case) == DIGESTS[core][case]


@pytest.mark.parametrize("case", CASES)
def test_the_pid_outputs_in_floats_and_over_arrays_are_the_same_numbers(case, monkeypatch):
    monkeypatch.setattr(loop_module, "FLOAT_LAW_LOOPS", 0)
    arrays = _outputs(case)
    # by einsum, a tick a block in two vectors that change places (as thousands of loops run)
    with monkeypatch.context() as m:
        m.setattr(loop_module, "EINSUM_LAW_LOOPS", 0)
        m.setattr(loop_module, "SHARED_BLOCK_FLOATS", 1)
        np.testing.assert_array_equal(_outputs(case), arrays)
    monkeypatch.setattr(loop_module, "FLOAT_LAW_LOOPS", 100)
    np.testing.assert_array_equal(_outputs(case), arrays)


if __name__ == "__main__":
    print(f'    "{_openblas_core()}": {{')
    for case in CASES:
        print(f'        "{case}": "{_digest(case)}",')
    print("    },")
