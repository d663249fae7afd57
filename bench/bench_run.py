"""Field-run speed: the built-in default (22 ha) and large (50 ha) scenarios.

Figures:
- ``run_default_wall_s``, ``run_large_wall_s``: wall time of `services.sim.run.run` (build, SUMO, sensors,
  control loop, landing and metrics; what `vrsim run` reports as wall_time_s);
- ``run_default_section_drives_wall_s``: the same for the default scenario with a drive per section
  (``[implement] kind = "section_drives"``: six loops, each rate at its own section's landing point);
- ``run_default_sprayer_wall_s``: the same for the default scenario with a boom sprayer (``kind =
  "sprayer"``, a liquid product: one flow loop, the boom's strips);
- ``run_default_spinner_wall_s``: the same for the default scenario with a twin-disc spinner
  (``[implement] kind = "spinner"``, its two sides as sections, a 24 m triangular spread at the 12 m
  driving width: two loops, each side's rate at its own landing point, product thrown 8 m behind);
- ``run_default_realtime_factor``: simulated over wall time for the default scenario;
- ``run_default_ticks_per_s``; ``run_default_<stage>_share``: the share of the wall time per stage;
- ``run_default_cli_wall_s``: the whole `vrsim run --quiet` command of the default scenario, Python
  start-up, imports and every output file included (summary.json, three GeoTIFFs, track.parquet and
  track.csv, the TASKDATA TimeLog, as_applied_points.gpkg, two PNGs, report.html); the best of three runs (the
  machine's noise is a few tenths of a second);
- ``run_huge_wall_s``, ``run_huge_peak_rss_mb``: the whole `vrsim run huge --quiet --out DIR` command
  of the built-in 540 ha scenario (1.6 million ticks), outputs included: its wall time and the peak
  resident memory of its largest process (the run's own, SUMO's or a picture's), MB; one run each.

    .venv/bin/python -m bench.bench_run
"""

import os
import subprocess
import sys
import tempfile
import time

from vrsim.services.sim import run as run_field
from vrsim.services.sim import scenario


def _in_process(name: str, **tables) -> dict:
    sc = scenario.load(name)
    if tables:   # table -> its keys changed
        sc = scenario.with_changes(sc, **tables)
    run_field(sc)  # warm: the SUMO network cache and lazy imports
    best = None
    for _ in range(2):
        result = run_field(sc)
        if best is None or result.summary["wall_time_s"] < best.summary["wall_time_s"]:
            best = result
    return best.summary


def _cli_wall_s(name: str, runs: int = 3) -> float:
    vrsim = os.path.join(os.path.dirname(sys.executable), "vrsim")
    best = float("inf")
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            subprocess.run([vrsim, "run", name, "--quiet", "--out", out], check=True, capture_output=True)
            best = min(best, time.perf_counter() - t0)
    return best


def run_default_section_drives_wall_s() -> float:
    """The default scenario's run with ``section_drives`` (best of two, after a warm-up run), s."""
    return _in_process("default", implement={"kind": "section_drives"})["wall_time_s"]


def run_default_sprayer_wall_s() -> float:
    """The default scenario's run with a boom sprayer (``kind = "sprayer"``: air-induction 04 nozzles at
    1-8 bar, which cover the default map at its speeds, flow control; a liquid of 1.0 kg/L), best of
    two after a warm-up run, s (tests/accuracy/scenarios/sprayer_default_field.toml is the same)."""
    sprayer = {"kind": "sprayer", "nozzle": "04", "pressure_range_bar": [1.0, 8.0]}
    liquid = {"form": "liquid", "density_kg_l": 1.0}
    return _in_process("default", implement=sprayer, product=liquid)["wall_time_s"]


# A fresh process runs the command: its children's peak resident memory is the command's processes'.
_PEAK_PROBE = ("import resource, subprocess, sys, time\n"
               "t0 = time.perf_counter()\n"
               "subprocess.run(sys.argv[1:], check=True, capture_output=True)\n"
               "print(time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n")


def cli_wall_and_peak(name: str) -> tuple[float, float]:
    """Wall time (s) of ``vrsim run NAME --quiet --out DIR`` and the peak resident memory of its
    largest process (MB)."""
    vrsim = os.path.join(os.path.dirname(sys.executable), "vrsim")
    with tempfile.TemporaryDirectory() as out:
        command = [vrsim, "run", name, "--quiet", "--out", out]
        done = subprocess.run([sys.executable, "-c", _PEAK_PROBE, *command], check=True, capture_output=True,
                              text=True)
    wall_s, peak_kb = done.stdout.split()
    return float(wall_s), float(peak_kb) / 1024.0


def run_default_spinner_wall_s() -> float:
    """The default scenario's run with a ``spinner`` (best of two, after a warm-up run), s."""
    spinner = {"kind": "spinner", "sections": 2, "spread_width_m": 24.0}
    return _in_process("default", implement=spinner)["wall_time_s"]


def run() -> dict:
    default = _in_process("default")
    large = _in_process("large")
    figures = {
        "run_default_wall_s": default["wall_time_s"],
        "run_default_section_drives_wall_s": run_default_section_drives_wall_s(),
        "run_default_sprayer_wall_s": run_default_sprayer_wall_s(),
        "run_default_spinner_wall_s": run_default_spinner_wall_s(),
        "run_large_wall_s": large["wall_time_s"],
        "run_default_realtime_factor": default["realtime_factor"],
        "run_large_realtime_factor": large["realtime_factor"],
        "run_default_ticks_per_s": default["ticks"] / default["wall_time_s"],
        "run_default_cli_wall_s": _cli_wall_s("default"),
    }
    figures["run_huge_wall_s"], figures["run_huge_peak_rss_mb"] = cli_wall_and_peak("huge")
    for stage, seconds in default["stage_s"].items():
        figures[f"run_default_{stage.removesuffix('_s')}_share"] = seconds / default["wall_time_s"]
    return figures


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:<36} {value:,.4g}")
