"""What `vrsim serve aog-rc` writes beside a run's usual outputs: aog_rc.json (the counters and each
sensor's end state), aog_rc.csv (per 50 ms and sensor: what the app asked, what the module measured and
drove, the PID's integral) and aog_rc.png (the PID over time). Each file whole or not at all."""

from __future__ import annotations

import csv
import os

import numpy as np

from vrsim.common.written import written
from vrsim.services.outputs.encode import dumps_text

__all__ = ["write_aog_files"]


def write_aog_files(service, out_dir: str, settings: dict) -> dict[str, str]:
    """aog_rc.json, aog_rc.csv and aog_rc.png of `service` (`services.aog.service.AogService`) into
    `out_dir` (created); `settings`: what the run was started with. Returns {name: path}."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {name: os.path.join(out_dir, name) for name in ("aog_rc.json", "aog_rc.csv", "aog_rc.png")}
    doc = {"settings": settings, **service.status()}
    with written(paths["aog_rc.json"]) as temp, open(temp, "w") as fh:
        fh.write(dumps_text(doc, indent=True) + "\n")
    rows = service.timeline.rows
    with written(paths["aog_rc.csv"]) as temp, open(temp, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(service.timeline.COLUMNS)
        out.writerows(rows)
    _picture(rows, service.timeline.COLUMNS, paths["aog_rc.png"])
    return paths


def _picture(rows: list[tuple], columns: tuple, path: str) -> None:
    """Per sensor: target and measured units/min, the true flow, and the PWM beneath."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    col = {name: i for i, name in enumerate(columns)}
    keys = sorted({(r[col["module"]], r[col["sensor"]]) for r in rows}) or [(0, 0)]
    fig, axes = plt.subplots(2, len(keys), figsize=(7 * len(keys), 6), sharex=True, squeeze=False)
    for j, key in enumerate(keys):
        part = np.array([[r[col[c]] for c in ("time_s", "target_upm", "applied_upm", "true_upm", "pwm",
                                              "output_pwm")] for r in rows
                         if (r[col["module"]], r[col["sensor"]]) == key], dtype=float).reshape(-1, 6)
        top, bottom = axes[0, j], axes[1, j]
        top.plot(part[:, 0], part[:, 1], label="app's target", color="k", lw=1)
        top.plot(part[:, 0], part[:, 2], label="module's reading (pulses)", lw=1)
        top.plot(part[:, 0], part[:, 3], label="plant's flow", lw=0.8, alpha=0.7)
        top.set_ylabel("units/min")
        top.set_title(f"module {key[0]}, sensor {key[1]}")
        top.legend(loc="best", fontsize=8)
        bottom.plot(part[:, 0], part[:, 4], label="PID output (32400 PWM)", lw=1)
        bottom.plot(part[:, 0], part[:, 5], label="driven (AdjustFlow)", lw=0.8)
        bottom.set_ylabel("PWM")
        bottom.set_xlabel("time, s")
        bottom.legend(loc="best", fontsize=8)
    fig.tight_layout()
    with written(path) as temp:
        fig.savefig(temp, dpi=90, format="png")
    plt.close(fig)
