"""vrsim's Python API in one script: load a scenario, change it in code, run it, read the summary and
the arrays, write the outputs.

    .venv/bin/python scenarios/python_api.py [OUT_DIR]

Runs `quick_rectangle.toml` (beside this script) on a zone map at its working speed and again 60 %
faster, prints how far each applied rate was from the prescription and how long and how far the rate
transitions took, and writes the faster run's files (summary.json, GeoTIFFs, track.parquet, plots,
report.html) to OUT_DIR (default: runs/python-api).
"""

from __future__ import annotations

import os
import sys

import numpy as np

from vrsim.services.outputs.write import write_outputs
from vrsim.services.sim.metrics import METRICS
from vrsim.services.sim.run import run
from vrsim.services.sim.scenario import load, with_changes

HERE = os.path.dirname(os.path.abspath(__file__))
SHOWN = ("mae_kg_ha", "within_10pct_area_pct", "transition_time_s_mean", "transition_distance_m_mean")


def main(out_dir: str) -> int:
    loaded = load(os.path.join(HERE, "quick_rectangle.toml"))  # a file, or a built-in name: "default"
    # Management zones instead of its smooth map, so the rate steps (and transitions can be timed).
    base = with_changes(loaded, name="quick_zones", map={"synthetic": "zones", "params": {"n_zones": 6}})
    speed = base.tractor.working_speed_m_s
    fast = with_changes(base, name="quick_zones_fast", tractor={"working_speed_m_s": 1.6 * speed})

    units = {m.key: m.unit for m in METRICS}
    print(f"{'scenario':<22}{'speed m/s':>10}" + "".join(f"{k + ' ' + units[k]:>32}" for k in SHOWN))
    for scenario in (base, fast):
        result = run(scenario)  # everything in process: SUMO, sensors, controller, landing, metrics
        summary = result.summary  # the keys of `vrsim run --json`
        print(f"{scenario.name:<22}{scenario.tractor.working_speed_m_s:>10.2f}"
              + "".join(f"{summary[k]:>32.3f}" for k in SHOWN))

    # Per-tick arrays of the last run (numpy, one value per 50 ms tick) and the as-applied raster.
    rpm, target = result.control["shaft_rpm"], result.control["target_shaft_rpm"]
    on = result.track["implement_on"]
    applied = result.as_applied.applied_kg_ha  # kg/ha on the prescription's grid
    print(f"{len(rpm):,} ticks; shaft speed error while applying: {np.abs(rpm - target)[on].mean():.2f} "
          f"rpm mean; applied in the field: {np.nanmean(applied[result.in_field]):.1f} kg/ha mean")

    paths = write_outputs(result, out_dir)
    print(f"wrote {', '.join(sorted(paths))} in {out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else os.path.join("runs", "python-api")))
