"""Two controllers over one drive, their rate error over time: `RunResult.to_pandas` in ten lines.

    .venv/bin/python scenarios/two_controllers.py [OUT.png]

SUMO drives `quick_rectangle.toml` (beside this script) once on a zone map; the paper's PID and the
Smith predictor each run over that same drive (`control_and_account`), and the plot shows each one's
applied minus prescribed rate (kg/ha) per tick against time (s). Prints each run's MAE (kg/ha, the
summary's, over the as-applied raster's cells: not the per-tick mean the plot shows). Writes OUT.png
(default: runs/two_controllers.png).
"""

import os
import sys

import matplotlib

matplotlib.use("Agg")  # a file, no window
import matplotlib.pyplot as plt  # noqa: E402

from vrsim.services.sim import control_and_account, drive, load, with_changes  # noqa: E402


def main(out_png: str) -> int:
    base = load(os.path.join(os.path.dirname(os.path.abspath(__file__)), "quick_rectangle.toml"))
    scenario = with_changes(base, map={"synthetic": "zones", "params": {"n_zones": 6}})
    driven = drive(scenario)  # SUMO once: the track and sensors do not depend on the controller
    for kind in ("pid", "smith"):
        result = control_and_account(driven, with_changes(scenario, controller={"kind": kind}).controller)
        ticks = result.to_pandas().dropna(subset=["applied_kg_ha"])  # ticks that put product down
        plt.plot(ticks.time_s, ticks.applied_kg_ha - ticks.prescribed_kg_ha, lw=0.5, label=kind)
        print(f"{kind}: MAE {result.summary['mae_kg_ha']:.3f} kg/ha over {len(ticks):,} ticks")
    plt.title("two controllers over one drive"), plt.xlabel("time (s)")
    plt.ylabel("applied - prescribed (kg/ha)"), plt.legend()
    os.makedirs(os.path.dirname(os.path.abspath(out_png)), exist_ok=True)
    plt.savefig(out_png, dpi=120)
    print(f"wrote {out_png}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else os.path.join("runs", "two_controllers.png")))
