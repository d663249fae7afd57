"""The colour scale the page paints rates with, and the prescription rendered once to a PNG with it.

The page colours the live as-applied cells with the same table (`scale` sends it), so prescribed and
applied read on one scale: the prescription's range, kg/ha; its legend reads in the map's own unit.
"""

from __future__ import annotations

import io
import math

import numpy as np

from vrsim.maps.units import KG_HA, is_rate_unit, rate_unit

LUT_SIZE = 256
MAX_UNIT_CHARS = 32  # a unit from the bus longer than this is not parsed (pint's parser is no sandbox)


def scale(info: dict) -> dict:
    """``{"vmin_kg_ha", "vmax_kg_ha", "vmin", "vmax", "unit", "lut": [[r, g, b], ...]}``: viridis over
    the map's rate range (from ``map/info``; a flat or unknown range becomes 0 .. max, or 0 .. 1), and
    that range in the map's own unit (``rate_unit``, ``min_rate``, ``max_rate``) for the legend; the
    legend stays in kg/ha where the reply does not give them (the bus is untrusted input)."""
    from matplotlib import colormaps

    lo, hi = info.get("min_rate_kg_ha"), info.get("max_rate_kg_ha")
    known = _finite(lo) and _finite(hi)
    lo = float(lo) if _finite(lo) else 0.0
    hi = float(hi) if _finite(hi) else 1.0
    if hi <= lo:
        lo, hi, known = 0.0, max(hi, 1.0), False
    rgb = np.round(colormaps["viridis"](np.linspace(0.0, 1.0, LUT_SIZE))[:, :3] * 255).astype(int)
    legend = {"vmin": lo, "vmax": hi, "unit": KG_HA}
    unit, lo_u, hi_u = info.get("rate_unit"), info.get("min_rate"), info.get("max_rate")
    short = isinstance(unit, str) and len(unit) <= MAX_UNIT_CHARS
    if known and short and is_rate_unit(unit) and _finite(lo_u) and _finite(hi_u):
        legend = {"vmin": float(lo_u), "vmax": float(hi_u), "unit": rate_unit(unit)}
    return {"vmin_kg_ha": lo, "vmax_kg_ha": hi, **legend, "lut": rgb.tolist()}


def _finite(value) -> bool:
    return type(value) in (int, float) and math.isfinite(value)


def render_png(rates_kg_ha: np.ndarray, rows: int, cols: int, colours: dict) -> bytes:
    """A rows x cols PNG of ``rates_kg_ha`` (row-major, row 0 north) on ``colours`` (`scale`);
    nodata (NaN) transparent."""
    from PIL import Image

    lut = np.asarray(colours["lut"], dtype=np.uint8)
    lo, hi = colours["vmin_kg_ha"], colours["vmax_kg_ha"]
    rates = np.asarray(rates_kg_ha, dtype=np.float64).reshape(rows, cols)
    known = np.isfinite(rates)
    level = np.clip((np.where(known, rates, lo) - lo) / (hi - lo) * (LUT_SIZE - 1), 0, LUT_SIZE - 1)
    rgba = np.zeros((rows, cols, 4), dtype=np.uint8)
    rgba[..., :3] = lut[np.round(level).astype(int)]
    rgba[..., 3] = np.where(known, 255, 0)
    out = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(out, format="PNG", optimize=False)
    return out.getvalue()
