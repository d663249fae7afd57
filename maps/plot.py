"""A quick-look PNG of a map (matplotlib, headless)."""

from __future__ import annotations

import numpy as np

from vrsim.common import MapError
from vrsim.maps.crs import crs_label
from vrsim.maps.grid import Grid


def plot_map(grid: Grid, path: str, title: str | None = None) -> None:
    """Draw the rates (kg/ha) with a colour bar, axes in the grid's CRS, nodata blank."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    west, south, east, north = grid.bounds
    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    try:
        # Big rasters are decimated for display: a PNG has a few hundred pixels per side anyway.
        step = max(1, max(grid.rows, grid.cols) // 2000)
        rates = np.ma.masked_invalid(grid.rates_kg_ha[::step, ::step])
        im = ax.imshow(rates, extent=(west, east, south, north), origin="upper", cmap="viridis",
                       interpolation="nearest", aspect="equal")
        fig.colorbar(im, ax=ax, label=f"rate ({grid.unit})")
        unit = "deg" if grid.crs.is_geographic else "m"
        ax.set_xlabel(f"x ({unit})")
        ax.set_ylabel(f"y ({unit})")
        ax.set_title(title or f"{grid.product or 'prescription'} - {crs_label(grid.crs)[:40]}")
        ax.ticklabel_format(useOffset=False, style="plain")
        fig.tight_layout()
        fig.savefig(path)
    except (OSError, ValueError) as exc:
        raise MapError(f"{path}: cannot write the plot: {exc}") from None
    finally:
        plt.close(fig)
