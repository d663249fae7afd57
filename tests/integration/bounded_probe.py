"""Feed hostile files to the readers in a fresh process and report time, error and peak memory:
``python -m tests.integration.bounded_probe CASES.json`` prints one JSON line per case (label, seconds,
error class, message) as it goes, then ``{"baseline_kb": ..., "peak_kb": ...}``: the peak resident set
(``ru_maxrss``) after the imports and after every case, so peak - baseline bounds every case."""

from __future__ import annotations

import json
import resource
import sys
import time


def read(kind: str, path: str):
    from vrsim import maps
    from vrsim.vehicle import Field

    if kind == "map":
        return maps.read_map(path)
    if kind == "field":
        return Field.from_file(path)
    if kind == "rectangle":
        width_m, length_m = map(float, path.split("x"))
        return Field.rectangle(width_m, length_m)
    raise ValueError(kind)


def main() -> None:
    from vrsim import (
        maps,  # noqa: F401 - the imports are the baseline, not part of any case
        vehicle,  # noqa: F401
    )
    from vrsim.common import VrsimError

    with open(sys.argv[1]) as fh:
        cases = json.load(fh)
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for label, kind, path in cases:
        print(json.dumps({"start": label}), flush=True)
        t0 = time.monotonic()
        try:
            read(kind, path)
            outcome = {"error": None, "message": ""}
        except VrsimError as exc:
            outcome = {"error": type(exc).__name__, "message": str(exc)}
        print(json.dumps({"label": label, "seconds": time.monotonic() - t0, **outcome}), flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"baseline_kb": baseline, "peak_kb": peak}), flush=True)


if __name__ == "__main__":
    main()
