"""The deposition engine: product actually put down, accumulated through a machine's footprint onto a
prescription's grid.

One algorithm, two modes:

- `AsApplied` (this module): deposit batches of items one after another (a run's strips at once, or
  the live page's rate samples as they arrive) and read the rasters at any time;
- `maps.ColumnDeposit` (`maps.columns`): one footprint's geometry mapped to the raster once, then
  applied to many mass columns at once (the same strips carrying several controllers' product).

Both take the items' geometry from a footprint (`maps.footprint`: today's kind is `Strips`, a
rectangle per section along the track; a spinner's pattern or a sprayer's nozzles are new kinds)
and spread each sample over the sub-cells it overlaps (`maps.subcells`), vectorized (no per-item
Python); both read the same figures by the same per-sub-cell rules: rates (kg/ha), coverage, passes
and overlap.

Accuracy (strips): the total is exact (every kilogram lands in a cell or in `outside_kg`). For strips
travelling along the grid axes the split is exact, whatever the strip length (ticks of a few cm
included). For oblique strips the bounding box smears each sub-rectangle by up to h (half a sub-cell)
across a cell edge: measured per-cell errors are below 0.5 % at any heading with full coverage
(tests). Coverage is exact for axis-aligned swaths and within ~1.5 % per cell for oblique ones (the
box smear moves swept area into neighbours, and the clip at 1 drops the excess); where two passes
partly overlap inside one sub-cell it can be over-counted (the overlap counts twice before the
clip), an error of at most one sub-cell along the overlap's edge. Items carrying no product (sections
off) sweep no coverage.

Passes: items may carry the pass they belong to (a stretch of path between turns). Each pass is
accumulated on its own raster over the window of sub-cells it touches, then added to the rest,
which gives, per cell, how many passes put product on it (`pass_count`), the area more than one
pass swept (`overlap_fraction`) and the product beyond the first pass (`overlap_kg`), at a cost
that grows with the passes' area, not with the grid's.
"""

from __future__ import annotations

import numpy as np

from vrsim.common import MapError
from vrsim.maps.crs import metres_per_unit
from vrsim.maps.footprint import Footprint, Samples, Strips
from vrsim.maps.grid import Grid
from vrsim.maps.pass_capped import CappedSums
from vrsim.maps.subcells import SubcellRaster


class AsApplied:
    """Accumulates applied product on the grid of a prescription (a projected, metric CRS).

    Parameters
    ----------
    grid : Grid
        The prescription (only its geometry is used); its CRS must be projected.
    subcells : int
        Sub-cells per cell side of the accumulation raster (default 2); footprints are sampled at
        half a sub-cell.
    """

    def __init__(self, grid: Grid, subcells: int = 2):
        self.grid = grid
        self.raster = checked_raster(grid, subcells, "AsApplied")
        self._cell_area_m2 = grid.cell_area_m2  # refuses lon/lat grids with a clear message
        # Real part: mass in kg; imaginary part: swept area in CRS units^2, so one np.add.at updates
        # both.
        self._acc = np.zeros(self.raster.size, dtype=np.complex128)
        self.total_kg = 0.0
        self.items = 0  # items deposited
        # Pass accounting (see `deposit`'s pass_index). The open pass deposits into its own raster
        # (`_pass_acc`, a new one per pass), over a window of sub-cells `_window`; when it closes,
        # that window is added to `_acc`, and to the capped swept-area sums (`_capped`, per interior
        # sub-cell) and the pass count (`_count`, per cell) of the closed passes.
        self._pass = None
        self._pass_acc = None
        self._window = None  # [row_min, row_max, col_min, col_max] touched, ring coordinates
        self._tiles = None   # the open pass's touched tiles (`_mark_tiles`)
        self._capped = CappedSums((grid.rows * subcells, grid.cols * subcells), self.raster.sub_area)
        self._count = np.zeros((grid.rows, grid.cols), dtype=np.int32)   # read as int64 (`pass_count`)
        self._target = self._acc  # where `_spread` deposits
        self._kept = None    # after `finish`: the per-cell figures, the sub-cell rasters given back

    def _all(self) -> np.ndarray:
        """The accumulator with the open pass's deposits (flat, ring included)."""
        return self._acc if self._pass is None else self._acc + self._pass_acc

    # --- reads ---------------------------------------------------------------------------------
    # Each per-cell read goes band by band of cell rows (`cell_bands`): its temporaries are a band's, not
    # the grid's sub-cells' (four times the cells, and a pass's raster added), the figures the same bits.
    def _blocks(self, rows: slice) -> np.ndarray:
        """The accumulator with the open pass's deposits, interior sub-cells of the cell rows `rows` as
        (band rows, s, cols, s) blocks."""
        part = self.raster.interior(self._acc)[rows]
        return part if self._pass is None else part + self.raster.interior(self._pass_acc)[rows]

    @property
    def applied_kg(self) -> np.ndarray:
        """Applied product per cell, kg, shape (rows, cols)."""
        if self._kept is not None:
            return self._kept["applied_kg"]
        return cell_bands(self.raster, lambda rows: self.raster.cell_sums(self._blocks(rows).real))

    def applied_kg_in(self, rows: slice, cols: slice) -> np.ndarray:
        """`applied_kg` of a window of cells (slices of rows and columns, steps of 1), reading only
        its sub-cells: for a reader that follows deposits as they arrive (the live page)."""
        if self._kept is not None:
            return self._kept["applied_kg"][rows, cols].copy()
        s = self.raster.subcells
        r0, r1, _ = rows.indices(self.grid.rows)
        c0, c1, _ = cols.indices(self.grid.cols)
        window = (slice(1 + r0 * s, 1 + r1 * s), slice(1 + c0 * s, 1 + c1 * s))
        part = self._acc.reshape(self.raster.shape)[window].real
        if self._pass is not None:
            part = part + self._pass_acc.reshape(self.raster.shape)[window].real
        return self.raster.cell_sums(part.reshape(max(r1 - r0, 0), s, max(c1 - c0, 0), s))

    @property
    def applied_kg_ha(self) -> np.ndarray:
        """Applied product per cell, kg/ha, shape (rows, cols)."""
        return self.applied_kg * (10_000.0 / self._cell_area_m2)

    @property
    def outside_kg(self) -> float:
        """Product that fell outside the grid, kg."""
        if self._kept is not None:
            return self._kept["outside_kg"]
        return float(self.raster.ring_sum(self._all().real[None, :])[0])

    @property
    def coverage_fraction(self) -> np.ndarray:
        """Share of each cell's area that product was applied to, in [0, 1], shape (rows, cols)."""
        if self._kept is not None:
            return self._kept["coverage_fraction"]
        raster = self.raster
        return cell_bands(raster, lambda rows: raster.cell_means(raster.covered(self._blocks(rows).imag)))

    def as_grid(self) -> Grid:
        """The applied rates as a `Grid` on the prescription's geometry (cells never covered: NaN)."""
        rates = np.where(self.coverage_fraction > 0, self.applied_kg_ha, np.nan)
        g = self.grid
        return Grid(rates, g.transform, g.crs, product=g.product, source="as-applied", format="as-applied",
                    map_unit=g.map_unit, density_kg_l=g.density_kg_l, seed_mass_g=g.seed_mass_g)

    @property
    def pass_count(self) -> np.ndarray:
        """Number of passes that put product on at least half of each cell, shape (rows, cols) (items
        deposited without a pass index count for none)."""
        count = self._count_with_open_pass() if self._kept is None else self._kept["pass_count"]
        return count.astype(np.int64)

    @property
    def overlap_fraction(self) -> np.ndarray:
        """Share of each cell's area swept by more than one pass, in [0, 1], shape (rows, cols).

        Per sub-cell: the passes' swept areas (each capped at the sub-cell's area) summed, less the
        sub-cell's area; a lower bound of the area two passes share, exact when each covers whole
        sub-cells. A pass that sweeps the same ground twice (a turn) does not overlap itself.
        """
        if self._kept is not None:
            return self._kept["overlap_fraction"]
        raster, capped = self.raster, self._capped_bands()
        return cell_bands(raster, lambda rows: raster.cell_means(raster.overlap_share(capped(rows))))

    @property
    def overlap_kg(self) -> np.ndarray:
        """Product applied beyond the first pass on each cell, kg, shape (rows, cols): per sub-cell,
        its product times the share of its passes' swept area that overlaps."""
        if self._kept is not None:
            return self._kept["overlap_kg"]
        raster, capped = self.raster, self._capped_bands()
        return cell_bands(raster, lambda rows: raster.cell_sums(self._blocks(rows).real
                                                               * raster.beyond_first(capped(rows))))

    def finish(self) -> None:
        """The deposits are over: close the open pass, read each per-cell figure once and give back the
        sub-cell rasters (on a 534 ha map at 2 m cells, 170 MB for 60 MB of figures). The reads then
        give those figures (read-only arrays), the same bits; a deposit is refused."""
        if self._kept is not None:
            return
        self.close_pass()
        kept = {name: getattr(self, name) for name in _KEPT}
        kept["pass_count"] = self._count
        for value in kept.values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
        self._kept, self._acc, self._target, self._capped, self._count = kept, None, None, None, None

    # --- deposits ------------------------------------------------------------------------------
    def deposit(self, footprint: Footprint, mass_kg, pass_index=None, others=()) -> None:
        """Deposit a batch of items' product through their footprint.

        Parameters
        ----------
        footprint : Footprint
            Where the items put product (`maps.footprint`), in the grid's CRS.
        mass_kg : float or array_like, shape (items,)
            Product of each item, kg (>= 0).
        pass_index : int or array_like of int, shape (items,), optional
            The pass each item belongs to, for `pass_count` and the overlap figures. Items of one
            pass come together, passes one after another (across calls too); a pass ends where the
            index changes.
        others : sequence of (AsApplied, mass_kg) or (MeterTotals, masses), optional
            Other meters' product on the same items (each on the same grid and sub-cells), put there
            without passes: the samples and their sub-cells are worked out once for all (several
            meters' product on one run's strips). This raster's figures are those of a `deposit` of its
            own, bit for bit; theirs equal a `deposit` each up to the order of the sums (they go pass
            by pass, as this one does). A `maps.meter_totals.MeterTotals` takes the product of each of
            its meters, (items, meters).
        """
        if self._kept is not None:
            raise MapError("deposit: this as-applied raster is finished (AsApplied.finish): it takes no more")
        pairs = [(self, mass_kg), *others]
        masses = [acc._checked(mass, footprint.items) for acc, mass in pairs]
        step, unit = self.raster.step, metres_per_unit(self.grid.crs)
        for acc, _ in pairs:
            if isinstance(acc, AsApplied):
                acc._target = acc._acc
                if acc is not self or pass_index is None:   # swept area no pass owns: the sums dense
                    acc._capped.to_dense(acc._acc.reshape(acc.raster.shape)[1:-1, 1:-1].imag)
        if pass_index is None:
            runs = [(None, slice(0, footprint.items))]
        else:
            passes = np.broadcast_to(np.asarray(pass_index, dtype=np.int64).ravel(), masses[0].shape)
            runs = [(int(passes[lo]), slice(lo, hi)) for lo, hi in _pass_runs(passes)]
        for index, part in runs:
            if index is not None:
                self._begin_pass(index)
            for samples in footprint.samples(step, unit, part):
                terms = SubcellTerms(self.raster, samples)   # the sub-cells and shares, once for every meter
                for (acc, _), mass in zip(pairs, masses, strict=True):
                    acc._deposit(samples, mass[samples.items], terms)
        for (acc, _), mass in zip(pairs, masses, strict=True):
            acc._tally(mass)

    def add_strips(self, x0, y0, x1, y1, width_m, mass_kg, pass_index=None) -> None:
        """`deposit` through `maps.footprint.Strips` ``(x0, y0, x1, y1, width_m)``: strips of product,
        the arguments broadcast together."""
        x0, y0, x1, y1, width, mass = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64).ravel()
                                                          for v in (x0, y0, x1, y1, width_m, mass_kg)))
        self.deposit(Strips(x0, y0, x1, y1, width), mass, pass_index)

    def _deposit(self, samples: Samples, mass: np.ndarray, terms=None) -> None:
        """Spread `samples` carrying `mass` (per item); `terms`: `SubcellTerms` of the samples, if known."""
        n = samples.per_item
        area = np.where(mass > 0, samples.swept, 0.0)  # items carrying no product sweep no coverage
        if samples.weight is None:
            load = samples.flat((mass + 1j * area) / n)
        else:   # the load at the weights' shape (the same arithmetic per sample), copied to every sample once
            per_item = (samples.x.shape[0], *(1,) * (samples.x.ndim - 1))
            load = mass.reshape(per_item) * samples.weight + 1j * (area / n).reshape(per_item)
            load = np.broadcast_to(load, samples.x.shape).ravel()
        self._spread(SubcellTerms(self.raster, samples) if terms is None else terms, load)

    @staticmethod
    def _checked(mass_kg, items: int) -> np.ndarray:
        return _checked_mass(mass_kg, items)

    def _tally(self, mass: np.ndarray) -> None:
        self.total_kg += float(mass.sum())
        self.items += int(mass.size)

    def _spread(self, terms, load):
        """Split each sample's load between the (at most 2 x 2) sub-cells its box overlaps (`terms`:
        `SubcellTerms` of the samples, left unchanged)."""
        if self._target is not self._acc:
            self._widen_window(terms.r0, terms.c0)
        acc = self._target
        for corner in range(4):
            for part in terms.pieces():
                cells, wc, wr = terms.flat(corner, part)
                np.add.at(acc, cells, load[part] * wc * wr)

    # --- passes --------------------------------------------------------------------------------
    def close_pass(self) -> None:
        """End the open pass, if any: no more items of it come (a deposit of its index starts a pass
        of its own). The figures stay the same to the bit; the reads no longer add the open pass's
        raster to the rest, each on its own."""
        if self._pass is not None:
            self._close_pass()

    def _begin_pass(self, index: int) -> None:
        """Close the open pass if it is another, and deposit into pass `index`'s own raster."""
        if index != self._pass:
            if self._pass is not None:
                self._close_pass()
            self._pass_acc = np.zeros(self._acc.shape, self._acc.dtype)  # not zeros_like: it writes them
            self._pass = index
        self._target = self._pass_acc

    def _close_pass(self) -> None:
        """Add the open pass's raster to the rest, tile row by tile row over the runs of tiles its
        samples touched (`_tiles`): an oblique pass's window is a quarter of the grid, its tiles a few
        per cent. Everywhere else the pass's raster is zero, so the sums are the window's to the bit."""
        if self._window is not None:   # also a pass that put product off the grid only
            s, shape = self.raster.subcells, self.raster.shape
            acc, part = self._acc.reshape(shape), self._pass_acc.reshape(shape)
            for i0, i1, j0, j1 in self._slabs():   # interior sub-cells, whole cells
                inner = (slice(1 + i0, 1 + i1), slice(1 + j0, 1 + j1))
                swept = part[inner].imag
                self._capped.add_pass(slice(i0, i1), slice(j0, j1), acc[inner].imag, swept)
                acc[inner] += part[inner]
                blocks = self.raster.cell_sums(swept.reshape((i1 - i0) // s, s, (j1 - j0) // s, s))
                self._count[i0 // s: i1 // s, j0 // s: j1 // s] += self.raster.pass_puts_on(blocks)
            self._capped.end_pass()
            for ring in ((0, slice(None)), (-1, slice(None)), (slice(1, -1), 0), (slice(1, -1), -1)):
                acc[ring] += part[ring]   # what fell off the grid
        # The next pass gets a new raster (zeros the system maps as it writes them): this one's memory is
        # given back, where zeroing its window would keep every page any pass touched (the whole grid).
        self._pass, self._window, self._pass_acc, self._tiles = None, None, None, None

    def _slabs(self):
        """(i0, i1, j0, j1) interior sub-cell ranges (whole cells, no two overlapping) that hold every
        sub-cell the open pass's samples touched: per row of tiles, each run of touched tiles
        (`_tiles`)."""
        tile = _TILE * self.raster.subcells
        height, width = self.raster.shape[0] - 2, self.raster.shape[1] - 2
        for t in np.flatnonzero(self._tiles.any(axis=1)):
            edges = np.flatnonzero(np.diff(np.concatenate(([0], self._tiles[t], [0])).astype(np.int8)))
            i0, i1 = t * tile, min((t + 1) * tile, height)
            for a, b in zip(edges[0::2], edges[1::2], strict=True):
                yield i0, i1, a * tile, min(b * tile, width)

    def _mark_tiles(self, row, col) -> None:
        """Mark in `_tiles` the tiles of the sub-cells samples at `row`, `col` (ring coordinates) and
        their neighbours may touch: by runs of `_CHUNK` samples (consecutive samples mostly lie close
        together), sample by sample for a run that spreads wider than a tile (strips cut alike from
        both ends of a pass). Each box then spans at most two tiles a side: its corners' tiles are all."""
        tile = _TILE * self.raster.subcells
        height, width = self.raster.shape[0] - 2, self.raster.shape[1] - 2
        if self._tiles is None:
            self._tiles = np.zeros((-(-height // tile), -(-width // tile)), dtype=bool)
        starts = np.arange(0, row.size, _CHUNK)
        boxes = [np.minimum.reduceat(row, starts) - 1, np.maximum.reduceat(row, starts) + 1,
                 np.minimum.reduceat(col, starts) - 1, np.maximum.reduceat(col, starts) + 1]
        wide = (boxes[1] - boxes[0] >= tile) | (boxes[3] - boxes[2] >= tile)
        if wide.any():
            each = np.repeat(wide, np.diff(np.append(starts, row.size)))
            r, c = row[each], col[each]
            each_box = (r - 1, r + 1, c - 1, c + 1)
            boxes = [np.concatenate((b[~wide], e)) for b, e in zip(boxes, each_box, strict=True)]
        lo_r, hi_r = np.maximum(boxes[0] - 1, 0), np.minimum(boxes[1] - 1, height - 1)   # interior
        lo_c, hi_c = np.maximum(boxes[2] - 1, 0), np.minimum(boxes[3] - 1, width - 1)
        inside = (lo_r <= hi_r) & (lo_c <= hi_c)
        r0, r1, c0, c1 = (v[inside] // tile for v in (lo_r, hi_r, lo_c, hi_c))
        for r, c in ((r0, c0), (r0, c1), (r1, c0), (r1, c1)):
            self._tiles[r, c] = True

    def _open_pass_terms(self):
        """The open pass's capped swept area per sub-cell and whether it put product on each cell,
        over the interior window (whole cells) it touched: (capped, count, (row slice, col slice))."""
        if self._pass is None or self._window is None:
            return None, None, None
        s, shape, area = self.raster.subcells, self.raster.shape, self.raster.sub_area
        r0, r1, c0, c1 = self._window
        # Interior sub-cells (ring coordinates less one), widened to whole cells.
        i0, i1 = max(r0 - 1, 0) // s * s, -(-min(r1, shape[0] - 2) // s) * s
        j0, j1 = max(c0 - 1, 0) // s * s, -(-min(c1, shape[1] - 2) // s) * s
        if i1 <= i0 or j1 <= j0:
            return None, None, None
        swept = self._pass_acc.reshape(shape)[1 + i0: 1 + i1, 1 + j0: 1 + j1].imag
        blocks = self.raster.cell_sums(swept.reshape((i1 - i0) // s, s, (j1 - j0) // s, s))
        return np.minimum(swept, area), self.raster.pass_puts_on(blocks), (slice(i0, i1), slice(j0, j1))

    def _count_with_open_pass(self) -> np.ndarray:
        """Per cell the number of passes that swept at least half of it, the open pass included."""
        _, count, window = self._open_pass_terms()
        if window is None:
            return self._count
        rows, cols, s = *window, self.raster.subcells
        all_count = self._count.copy()
        all_count[rows.start // s: rows.stop // s, cols.start // s: cols.stop // s] += count
        return all_count

    def _capped_bands(self):
        """``capped(rows)``: per interior sub-cell of the cell rows `rows` the sum over passes of each
        pass's swept area (capped at the sub-cell's area), the open pass included, as (band rows, s,
        cols, s) blocks (`maps.pass_capped`)."""
        s = self.raster.subcells
        capped, _, window = self._open_pass_terms()
        swept = self._acc.reshape(self.raster.shape)[1:-1, 1:-1].imag

        def capped_rows(rows: slice) -> np.ndarray:
            sub = slice(rows.start * s, rows.stop * s)
            band = self._capped.band(sub, swept[sub])
            if window is not None:   # the open pass's, where the band crosses its window
                lo, hi = max(sub.start, window[0].start), min(sub.stop, window[0].stop)
                if lo < hi:
                    band[lo - sub.start: hi - sub.start, window[1]] += capped[lo - window[0].start:
                                                                              hi - window[0].start]
            return band.reshape(rows.stop - rows.start, s, self.grid.cols, s)

        return capped_rows

    def _widen_window(self, row, col) -> None:
        """Grow the open pass's window to the sub-cells of samples at `row`, `col` (ring coordinates)
        and their neighbours (a sample spills into one)."""
        if row.size == 0:
            return
        r0, r1 = int(row.min()) - 1, int(row.max()) + 1
        c0, c1 = int(col.min()) - 1, int(col.max()) + 1
        rows, cols = self.raster.shape
        self._mark_tiles(row, col)
        new = [max(r0, 0), min(r1, rows - 1), max(c0, 0), min(c1, cols - 1)]
        if self._window is not None:
            w = self._window
            new = [min(new[0], w[0]), max(new[1], w[1]), min(new[2], w[2]), max(new[3], w[3])]
        self._window = new


_CHUNK = 256   # samples per box of `AsApplied._mark_tiles` (a strip's samples go along it, then across)
_TILE = 16     # cells per side of the tiles of `AsApplied._tiles`
_KEPT = ("applied_kg", "coverage_fraction", "overlap_fraction", "overlap_kg", "outside_kg")  # by `finish`
_PIECE_SAMPLES = 1 << 16   # samples a piece of a deposit's batch holds (`SubcellTerms`)
_BAND_SUBCELLS = 1 << 19   # sub-cells a band of `cell_bands` holds at most (4 MB of floats; one row at least)


class SubcellTerms:
    """What a deposit needs of a batch of samples' boxes, the same for any load, in 48 bytes a sample:
    the sub-cells of each box's corners (`SubcellRaster.corners`, ring coordinates: r0, r1, c0, c1) and
    the shares that spill (wr, wc). The four corners' flat indices and shares are worked out a piece of
    `_PIECE_SAMPLES` samples at a time (`corner`): a deposit adds corner by corner over the batch, piece
    by piece, in the order of the whole batch's arrays (the same sums), with a piece's temporaries."""

    def __init__(self, raster: SubcellRaster, samples: Samples):
        self.r0, self.r1, self.c0, self.c1, self.wr, self.wc = raster.corners(
            samples.x.ravel(), samples.y.ravel(), samples.flat(samples.ext_x), samples.flat(samples.ext_y))
        self.cols = raster.shape[1]
        self.size = self.r0.size

    def pieces(self):
        """Consecutive slices of the samples, `_PIECE_SAMPLES` each."""
        return [slice(lo, lo + _PIECE_SAMPLES) for lo in range(0, self.size, _PIECE_SAMPLES)]

    def corner(self, corner: int, part: slice):
        """(rows, cols, column share, row share) of corner 0..3 (r0 c0, r0 c1, r1 c0, r1 c1) of the
        samples `part`: ring coordinates of its sub-cells, and the shares 1 - wc or wc, 1 - wr or wr."""
        high_r, high_c = divmod(corner, 2)
        rows, wr = (self.r1[part], self.wr[part]) if high_r else (self.r0[part], 1.0 - self.wr[part])
        cols, wc = (self.c1[part], self.wc[part]) if high_c else (self.c0[part], 1.0 - self.wc[part])
        return rows, cols, wc, wr

    def flat(self, corner: int, part: slice):
        """(flat sub-cell indices, column share, row share) of corner `corner` of the samples `part`."""
        rows, cols, wc, wr = self.corner(corner, part)
        return rows * self.cols + cols, wc, wr


def cell_bands(raster: SubcellRaster, per_band) -> np.ndarray:
    """A per-cell figure (rows, cols) worked out band by band of cell rows: ``per_band(rows)`` gives the
    cells of the rows `rows` (a slice), from their sub-cells; a band holds about `_BAND_SUBCELLS`."""
    rows, cols = raster.grid.rows, raster.grid.cols
    out = np.empty((rows, cols))
    step = max(1, _BAND_SUBCELLS // max(1, cols * raster.subcells**2))
    for r0 in range(0, rows, step):
        band = slice(r0, min(rows, r0 + step))
        out[band] = per_band(band)
    return out


def checked_raster(grid: Grid, subcells: int, who: str) -> SubcellRaster:
    """The sub-cell raster of `grid`; `MapError` for a grid that is none or a bad `subcells` (a
    lon/lat grid is refused by its `Grid.cell_area_m2`, which both modes read next)."""
    if not isinstance(grid, Grid):
        raise MapError(f"{who}: grid must be a maps.Grid, got {type(grid).__name__}")
    if not (isinstance(subcells, int) and 1 <= subcells <= 32):
        raise MapError(f"{who}: subcells={subcells!r} must be an integer in 1..32")
    return SubcellRaster(grid, subcells)


def _checked_mass(mass_kg, items: int) -> np.ndarray:
    """Each item's product as a flat float array of `items`; `MapError` if one is negative or not
    finite."""
    mass = np.broadcast_to(np.asarray(mass_kg, dtype=np.float64).ravel(), (items,))
    if not np.all(np.isfinite(mass) & (mass >= 0)):
        i = int(np.argmax(~(np.isfinite(mass) & (mass >= 0))))
        raise MapError(f"deposit: mass_kg[{i}]={mass[i]!r} must be finite and >= 0")
    return mass


def _pass_runs(passes: np.ndarray):
    """(start, stop) of each run of one pass index in `passes`."""
    cuts = np.concatenate(([0], np.flatnonzero(np.diff(passes)) + 1, [passes.size]))
    return [(int(lo), int(hi)) for lo, hi in zip(cuts[:-1], cuts[1:], strict=True) if hi > lo]
