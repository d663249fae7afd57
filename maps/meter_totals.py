"""Several meters' product on the same items, in a fraction of an `AsApplied` each: what a run's error
split reads of its reference meters (each meter's applied product per cell, coverage, product off the
grid), and nothing of passes.

A `MeterTotals` goes beside a run's own raster (`AsApplied.deposit`'s ``others``: the samples and their
sub-cells worked out once for every meter) or is deposited alone (`MeterTotals.deposit`). Per meter it
keeps:

- the product per cell, summed there directly in single precision (float32), where an `AsApplied` sums
  it per sub-cell in double precision and then the sub-cells; what fell off the grid in double
  precision: the same product to about one part in a million (float32 keeps 7 digits; a cell gets a
  few hundred shares of samples);
- the swept area per sub-cell (coverage is clipped per sub-cell) in single precision, shared by the
  meters that have put product on the same items so far: on a run's strips the reference meters lay
  product on the same items (a zero target is zero for each), so one raster serves them all. A meter
  that puts product on other items than the rest gets a copy of its shared raster at that deposit and
  goes on alone. The swept area is each meter's own: the same shares as `AsApplied`'s, added in its
  order, each sum rounded to single precision (a cell's coverage to 1e-7).

What the error split reads of them (its reference meters' mass balance and mean absolute error) is
thus the double-precision one's to about 1e-6 of itself, far below the two decimals it is shown with.
On a 534 ha map at 2 m cells (1.7 million cells) three meters take 21 MB of products and one 28 MB
raster of swept areas, where three `AsApplied` took 315 MB.
"""

from __future__ import annotations

import numpy as np

from vrsim.common import MapError
from vrsim.maps.as_applied import SubcellTerms, cell_bands, checked_raster
from vrsim.maps.crs import metres_per_unit
from vrsim.maps.footprint import Footprint, Samples
from vrsim.maps.grid import Grid


class MeterTotals:
    """The applied product of `meters` meters on one grid (a projected, metric CRS), without passes.

    Parameters
    ----------
    grid : Grid
        The prescription (only its geometry is used).
    meters : int
        How many meters.
    subcells : int
        Sub-cells per cell side of the swept-area raster (as `AsApplied`'s, whose deposits it goes beside).
    """

    def __init__(self, grid: Grid, meters: int, subcells: int = 2):
        self.grid = grid
        self.raster = checked_raster(grid, subcells, "MeterTotals")
        self._cell_area_m2 = grid.cell_area_m2  # refuses lon/lat grids with a clear message
        if not (isinstance(meters, int) and meters >= 1):
            raise MapError(f"MeterTotals: meters={meters!r} must be an integer >= 1")
        self.meters = meters
        self._cells = grid.rows * grid.cols
        self._kg = np.zeros((meters, self._cells), dtype=np.float32)   # per meter: kg per cell ...
        self._outside = np.zeros(meters)                                # ... and off the grid
        # Swept areas per sub-cell (ring included), and which one each meter's is.
        self._swept = [np.zeros(self.raster.size, dtype=np.float32)]
        self._of = [0] * meters
        self.total_kg = np.zeros(meters)
        self.items = 0

    # --- reads ---------------------------------------------------------------------------------
    def applied_kg_ha(self, meter: int) -> np.ndarray:
        """Meter `meter`'s applied product per cell, kg/ha, shape (rows, cols)."""
        kg = self._kg[meter].reshape(self.grid.rows, self.grid.cols)
        return np.multiply(kg, 10_000.0 / self._cell_area_m2, dtype=np.float64)

    def coverage_fraction(self, meter: int) -> np.ndarray:
        """Share of each cell's area meter `meter` put product on, in [0, 1], shape (rows, cols)."""
        raster = self.raster
        swept = raster.interior(self._swept[self._of[meter]])
        return cell_bands(raster, lambda rows: raster.cell_means(raster.covered(swept[rows].astype(float))))

    def outside_kg(self, meter: int) -> float:
        """Meter `meter`'s product that fell outside the grid, kg."""
        return float(self._outside[meter])

    # --- deposits ------------------------------------------------------------------------------
    def deposit(self, footprint: Footprint, masses) -> None:
        """Deposit a batch of items' product through their footprint on its own; `masses`: each item's
        product of each meter, kg, (items, meters) (or (items,) for one meter)."""
        masses = self._checked(masses, footprint.items)
        step, unit = self.raster.step, metres_per_unit(self.grid.crs)
        for samples in footprint.samples(step, unit, slice(0, footprint.items)):
            self._deposit(samples, masses[samples.items], SubcellTerms(self.raster, samples))
        self._tally(masses)

    def _checked(self, masses, items: int) -> np.ndarray:
        """Each item's product of each meter, (items, meters) floats; `MapError` if one is negative or
        not finite."""
        mass = np.asarray(masses, dtype=np.float64)
        mass = np.broadcast_to(mass.reshape(-1, 1) if mass.ndim <= 1 else mass, (items, self.meters))
        bad = ~(np.isfinite(mass) & (mass >= 0))
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise MapError(f"deposit: mass_kg[{i}, {j}]={mass[i, j]!r} must be finite and >= 0")
        return mass

    def _tally(self, masses: np.ndarray) -> None:
        self.total_kg += masses.sum(axis=0)
        self.items += int(masses.shape[0])

    def _deposit(self, samples: Samples, mass: np.ndarray, terms: SubcellTerms) -> None:
        """Spread `samples` carrying `mass` (per item and meter, (k, meters)), corner by corner of the
        boxes (`SubcellTerms`), piece by piece."""
        n = samples.per_item
        # Per item (or per sample, weighted) of each meter: its product's load, and per swept-area raster
        # the swept area's; each a piece at a time (`_piece`).
        per_item = (samples.x.shape[0], *(1,) * (samples.x.ndim - 1))
        loads = [m / n if samples.weight is None else m.reshape(per_item) * samples.weight for m in mass.T]
        swept = []
        for first, _ in self._groups(mass > 0):   # the swept area, per sub-cell
            # `AsApplied._deposit`'s load, whose imaginary part is the swept area: the same bits.
            area = np.where(mass[:, first] > 0, samples.swept, 0.0)
            load = ((mass[:, first] + 1j * area) / n).imag if samples.weight is None else area / n
            swept.append((self._swept[self._of[first]], load))
        for corner in range(4):
            for part in terms.pieces():
                rows, cols, wc, wr = terms.corner(corner, part)
                cells = self._cell_index(rows, cols)
                inside = cells < self._cells
                every = bool(inside.all())
                for j, load in enumerate(loads):
                    kg = _piece(load, samples, part) * wc * wr
                    if every:
                        np.add.at(self._kg[j], cells, kg.astype(np.float32))   # float32's own loop: fast
                    else:
                        np.add.at(self._kg[j], cells[inside], kg[inside].astype(np.float32))
                        off = kg[~inside]   # added one by one, as the cells: pieces do not change the sum
                        np.add.at(self._outside, np.full(off.size, j), off)
                subs = rows * terms.cols + cols
                for target, load in swept:
                    np.add.at(target, subs, (_piece(load, samples, part) * wc * wr).astype(np.float32))

    def _groups(self, on: np.ndarray) -> list:
        """(a meter, the meters sharing its swept-area raster) per raster, for a deposit whose items
        each meter puts product on are `on` (k, meters): the meters of a shared raster that put product
        on other items than its first meter get a copy of it (as it stands before the deposit) first."""
        groups = []
        for raster in sorted(set(self._of)):
            members = [j for j in range(self.meters) if self._of[j] == raster]
            while members:
                first = members[0]
                same = [j for j in members if np.array_equal(on[:, j], on[:, first])]
                if groups and groups[-1][2] == raster:   # not the raster's first group: a copy
                    self._swept.append(self._swept[raster].copy())
                    for j in same:
                        self._of[j] = len(self._swept) - 1
                groups.append((first, same, raster))
                members = [j for j in members if j not in same]
        return [(first, same) for first, same, _ in groups]

    def _cell_index(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The flat cell index (the last: off the grid) of sub-cells at `rows`, `cols` (ring coordinates)."""
        s = self.raster.subcells
        r, c = (rows - 1) // s, (cols - 1) // s
        inside = (r >= 0) & (r < self.grid.rows) & (c >= 0) & (c < self.grid.cols)
        return np.where(inside, r * self.grid.cols + c, self._cells)


def _piece(values: np.ndarray, samples: Samples, part: slice) -> np.ndarray:
    """The samples `part` (flat) of `values` given per item (k,) or at the samples' shape (broadcast
    from (k, ...)), as `Samples.flat` would give them, without the whole batch's flat copy."""
    lo, hi, _ = part.indices(samples.x.size)
    index = np.arange(lo, hi)
    if values.ndim == 1:   # per item
        return values[index // samples.per_item]
    item, within = np.divmod(index, samples.per_item)
    return np.broadcast_to(values, samples.x.shape)[(item, *np.unravel_index(within, samples.x.shape[1:]))]
