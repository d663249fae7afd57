"""A run's per-tick arrays as one tidy table: a row per control tick, a column per quantity, units in
the names (`RunResult.to_pandas`, `RunResult.tick_columns`).

Why some rates are NaN (the docstring of `tick_columns` says it per column): ``applied_kg_ha`` is a
tick's metered product over the strip its open sections covered (`services.sim.landing.
applied_rate_kg_ha`), so it does not exist in a tick with no section open, nor in one that travels
less than 1 cm. In the built-in default run that is 13.6 % of the ticks: 12.8 % with the implement
lifted (turns at the headland, the way to the first pass), 0.8 % with the implement down but every
section closed by section control (ground already covered), a few ticks standing at the start.
``prescribed_kg_ha`` is NaN where the strip's midpoint is off the prescription map.
"""

from __future__ import annotations

import numpy as np

from vrsim.common import VrsimError
from vrsim.common.section_masks import section_mask_codes

# The columns by their source, in table order (docs/api.md lists them as `tick_columns` does).
TRACK_COLUMNS = ("time_s", "x_m", "y_m", "heading_rad", "speed_m_s", "implement_on", "s_m", "segment_index")
MEASURED_COLUMNS = ("measured_x_m", "measured_y_m", "measured_speed_m_s")
# The control core's per-tick values (`services.sim.core.CONTROL_KEYS`), renamed where the table has
# the landed value of the same name: the controller's look-up happens at the landing point it predicts.
CONTROL_COLUMNS = {"landing_x_m": "lookahead_x_m", "landing_y_m": "lookahead_y_m",
                   "prescribed_kg_ha": "lookahead_prescribed_kg_ha", "target_shaft_rpm": "target_shaft_rpm",
                   "shaft_rpm": "shaft_rpm", "shaft_rev": "shaft_rev", "current_a": "current_a",
                   "metered_kg": "metered_kg", "width_on_m": "width_on_m"}
DRIVE_COLUMNS = {"drive_rate_kg_ha": "rate_kg_ha", "drive_target_rpm": "target_rpm", "drive_kg": "kg",
                 "drive_open": "open"}
LANDING_COLUMNS = {"x0_m": "landed_x0_m", "y0_m": "landed_y0_m", "x1_m": "landed_x1_m",
                   "y1_m": "landed_y1_m", "strip_length_m": "strip_length_m",
                   "prescribed_kg_ha": "prescribed_kg_ha", "applied_kg_ha": "applied_kg_ha"}


def tick_columns(result) -> dict[str, np.ndarray]:
    """The per-tick columns of an in-process run (`services.sim.run.RunResult`), each shape (ticks,).

    - the true track: ``time_s``, ``x_m``, ``y_m`` (field CRS, m), ``heading_rad`` (counter-clockwise
      from east), ``speed_m_s``, ``implement_on``, ``s_m`` (distance along the planned path),
      ``segment_index`` (the path segment driven);
    - the sensors: ``measured_x_m``, ``measured_y_m`` (GNSS fix), ``measured_speed_m_s``;
    - the controller: ``lookahead_x_m``, ``lookahead_y_m`` (the landing point it predicted),
      ``lookahead_prescribed_kg_ha`` (the map's rate there: what it aimed at), ``target_shaft_rpm``,
      ``shaft_rpm``, ``shaft_rev`` (revolutions in the tick), ``current_a``, ``metered_kg`` (product
      metered in the tick), ``width_on_m`` (width of the open sections);
    - the sections: ``sections_on`` (how many gates are open), ``section_mask`` and
      ``commanded_mask`` (which: hexadecimal bitmask, bit k the k-th section from the left, as in
      track.parquet);
    - with more than one metering drive, per drive k: ``drive{k}_rate_kg_ha``, ``drive{k}_target_rpm``,
      ``drive{k}_kg``, ``drive{k}_open``;
    - where the product landed (on the true path, the delivery delay later): ``landed_x0_m``,
      ``landed_y0_m``, ``landed_x1_m``, ``landed_y1_m`` (the strip's ends), ``strip_length_m``,
      ``prescribed_kg_ha`` (the map's rate at the strip's midpoint; NaN off the map) and
      ``applied_kg_ha`` (metered kg over the strip's open width times its length; NaN where no
      section is open or the strip is under 1 cm: turns and headland with the implement lifted,
      sections closed over covered ground, standstill). ``prescribed_kg_ha`` and ``applied_kg_ha``
      are track.parquet's columns of the same name.

    Raises
    ------
    VrsimError
        A run accounted part by part (``result.bounded``: `services.sim.streamed.run_streamed`, what
        `vrsim run` does) keeps no per-tick arrays: its ticks are in its track.parquet.
    """
    if result.bounded:
        raise VrsimError("this run was accounted part by part (run_streamed, `vrsim run`) and kept no "
                         "per-tick arrays: read its track.parquet (pandas.read_parquet), or run it with "
                         "vrsim.services.sim.run")
    track, control, landing = result.track, result.control, result.landing
    cols = {name: np.asarray(track[name]) for name in TRACK_COLUMNS if name in track}
    cols.update(measured_x_m=result.measured_x_m, measured_y_m=result.measured_y_m,
                measured_speed_m_s=result.measured_speed_m_s)
    cols.update({new: np.asarray(control[key]) for key, new in CONTROL_COLUMNS.items()})
    gates = np.asarray(control["sections_on"], bool)
    cols["sections_on"] = gates.sum(axis=1, dtype=np.int16)
    cols["section_mask"] = _masks(gates)
    if control.get("sections_commanded") is not None:
        cols["commanded_mask"] = _masks(np.asarray(control["sections_commanded"], bool))
    drives = np.asarray(control["drive_kg"]).reshape(len(gates), -1).shape[1]
    if drives > 1:
        for key, suffix in DRIVE_COLUMNS.items():
            values = np.asarray(control[key]).reshape(len(gates), drives)
            cols.update({f"drive{k}_{suffix}": values[:, k] for k in range(drives)})
    cols.update({new: np.asarray(getattr(landing, key)) for key, new in LANDING_COLUMNS.items()})
    return cols


def _masks(gates: np.ndarray) -> np.ndarray:
    codes, masks = section_mask_codes(gates)
    return np.asarray(masks, dtype=object)[codes]


def to_pandas(result):
    """`tick_columns` as a `pandas.DataFrame`, one row per tick (index: the tick)."""
    import pandas as pd

    frame = pd.DataFrame(tick_columns(result))
    frame.index.name = "tick"
    return frame
