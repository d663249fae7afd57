"""track.csv: one row per tick (time, position, speed, shaft, current, rates, sections).

Written column by column through pyarrow's CSV writer (177,000 rows in a fraction of a second, where a
row-by-row writer takes most of a second). A value that does not exist (a rate outside the map, the
applied rate at a standstill) is an empty field, so GIS tools and spreadsheets type the column as a
number. Each column is rounded to its resolution first, so the shortest text that reads back the same
number is short.
"""

from __future__ import annotations

import numpy as np

from common.section_masks import section_mask_codes
from services.sim.run import RunResult

# (column, decimals): 0.001 s, 1e-8 degree (~1 mm), 1 mm/s, 0.001 rpm, 0.01 mA, 0.01 kg/ha; None: as is
TRACK_COLUMNS = (("time_s", 3), ("lat", 8), ("lon", 8), ("speed_m_s", 3), ("target_shaft_rpm", 3),
                 ("shaft_rpm", 3), ("current_a", 5), ("prescribed_kg_ha", 2), ("applied_kg_ha", 2),
                 ("implement_on", None), ("sections_on", None), ("section_mask", None))


def write_track_csv(result: RunResult, path: str) -> None:
    """``sections_on`` counts the sections whose gates are open in the tick, ``section_mask`` says which
    (hexadecimal bitmask, bit k the k-th section from the left: `common.section_masks.section_masks`)."""
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    track, control, landing = result.track, result.control, result.landing
    lon, lat = result.world.field.to_wgs84(track["x_m"], track["y_m"])
    gates = np.asarray(control["sections_on"], bool)
    codes, masks = section_mask_codes(gates)
    values = (track["time_s"], lat, lon, track["speed_m_s"], control["target_shaft_rpm"],
              control["shaft_rpm"], control["current_a"], landing.prescribed_kg_ha, landing.applied_kg_ha,
              np.asarray(track["implement_on"], np.int8), gates.sum(axis=1, dtype=np.int16))
    columns = {name: pa.array(v if decimals is None else np.round(np.asarray(v, float), decimals),
                              from_pandas=True)  # from_pandas: NaN becomes null, written as ""
               for (name, decimals), v in zip(TRACK_COLUMNS[:-1], values, strict=True)}  # the masks next
    # Each distinct mask's text once: a dictionary column, written as its values.
    columns["section_mask"] = pa.DictionaryArray.from_arrays(pa.array(codes.astype(np.int32)), masks)
    # Nothing here holds a comma or a quote: no quotes (the masks would get them by default).
    options = pa_csv.WriteOptions(quoting_header="none", quoting_style="none")
    pa_csv.write_csv(pa.table(columns), path, options)
