"""The georeferenced prescription grid and point lookup.

A `Grid` is a north-up raster of application rates in kg/ha: ``rates_kg_ha[row, col]`` with row 0
the north row, an `affine.Affine` transform (rasterio convention: pixel (col, row) corner -> x, y),
a pyproj CRS, and nodata cells as NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pyproj
from affine import Affine

from vrsim.common import MapError, check_number, check_positive, files
from vrsim.maps.crs import WGS84, as_crs, crs_label, metres_per_unit, transform_xy
from vrsim.maps.units import KG_HA, convert_rate, rate_kind, rate_unit

UNIT = KG_HA
QUANTITIES = ("rate", "difference")  # what the values are: rates (>= 0), or signed differences of rates
LOOKUP_CHUNK = 32_768  # points per pass of Grid.lookup: its temporaries stay in L2 cache


@dataclass(frozen=True)
class LookupResult:
    """Rates at points: arrays of the points' broadcast shape.

    Attributes
    ----------
    rate_kg_ha : ndarray of float64
        The rate; NaN outside the grid or on a nodata cell.
    inside : ndarray of bool
        True where the point lies on the grid (even on a nodata cell).
    row, col : ndarray of int64
        The cell holding the point; -1 outside.
    """

    rate_kg_ha: np.ndarray
    inside: np.ndarray
    row: np.ndarray
    col: np.ndarray


@dataclass(eq=False)  # grids compare by identity: == on the rate arrays would be ambiguous
class Grid:
    """A prescription map: rates on a north-up grid in some CRS.

    Parameters
    ----------
    rates_kg_ha : array_like, shape (rows, cols)
        Rates in kg/ha, row 0 north; NaN marks nodata. Stored as C-contiguous float64 (no copy when
        it already is one).
    transform : affine.Affine
        Cell (col, row) corner to CRS coordinates; must be north-up (no rotation), ``a > 0``,
        ``e < 0``.
    crs : pyproj.CRS or str
        The grid's coordinate reference system.
    product : str
        Product name, for reports ("" when unknown).
    source : str
        File path, or ``"synthetic:<kind>"``.
    format : str
        ``"geotiff"``, ``"isoxml"``, ``"shapefile"``, ``"geojson"``, ``"csv"`` or ``"synthetic"``.
    unit : str
        The unit `rates_kg_ha` hold: ``"kg/ha"`` for every prescription (`maps.read_map` converts a
        map in lb/ac, or in L/ha with the product's density, once when it reads it); a grid in
        another rate unit (`maps.units.rate_unit`: a volume map without a density, an error map of a
        gal/ac log) is written and read back, but is no prescription (the field run refuses it).
    map_unit : str, optional
        The unit the map states its rates in, which its figures are shown and its files written in
        (`in_map_unit`); None: `unit`.
    density_kg_l : float, optional
        The product's density (kg/L) that converted a volume map to kg/ha, so figures convert back.
    seed_mass_g : float, optional
        The mass of one seed (g) that converted a count map (seeds/ha) to kg/ha, likewise.
    quantity : str
        ``"rate"`` (a prescription or an as-applied map: rates >= 0) or ``"difference"`` (signed,
        e.g. applied minus prescribed), which is no prescription.
    zone_rates_kg_ha : array_like, optional
        A vector map's zone rates, distinct and sorted, in `unit` (`maps.zones`: a cell its rasterizing
        covers with more than one zone holds their area-weighted mean, which no zone asks for); None:
        the cells' values are the map's rates (a raster).
    """

    rates_kg_ha: np.ndarray
    transform: Affine
    crs: pyproj.CRS
    product: str = ""
    source: str = ""
    format: str = ""
    unit: str = field(default=UNIT)
    quantity: str = "rate"
    map_unit: str | None = None
    density_kg_l: float | None = None
    seed_mass_g: float | None = None
    zone_rates_kg_ha: np.ndarray | None = None

    def __post_init__(self):
        rates = np.ascontiguousarray(self.rates_kg_ha, dtype=np.float64)
        if rates.ndim != 2 or rates.size == 0:
            raise MapError(f"{self._where()}: rates must be a non-empty 2-D array, got shape {rates.shape}")
        t = self.transform
        if not isinstance(t, Affine):
            raise MapError(f"{self._where()}: transform must be an affine.Affine, got {type(t).__name__}")
        if t.b != 0.0 or t.d != 0.0 or not (t.a > 0.0 and t.e < 0.0):
            raise MapError(f"{self._where()}: only north-up grids are supported (transform {tuple(t)[:6]}); "
                           "rotated or south-up rasters need warping first, e.g. with gdalwarp")
        if not all(math.isfinite(v) for v in tuple(t)[:6]):
            raise MapError(f"{self._where()}: transform has non-finite values {tuple(t)[:6]}")
        self.rates_kg_ha = rates
        if self.zone_rates_kg_ha is not None:
            self.zone_rates_kg_ha = np.unique(np.asarray(self.zone_rates_kg_ha, dtype=np.float64))
        self.crs = as_crs(self.crs, f"{self._where()}: crs")
        self.unit = rate_unit(self.unit, f"{self._where()}: unit")
        self.map_unit = rate_unit(self.map_unit or self.unit, f"{self._where()}: map unit")
        if self.quantity not in QUANTITIES:
            raise MapError(f"{self._where()}: quantity must be one of {QUANTITIES}, got {self.quantity!r}")
        # Scalars for the per-tick fast path, so rate_at does no attribute chasing through Affine.
        self._x0, self._dx, self._y0, self._dy = t.c, t.a, t.f, -t.e
        self._inv_dx, self._inv_dy = 1.0 / t.a, 1.0 / -t.e
        self._to_grid = None  # WGS84 -> grid transformer, made on first use

    def _where(self) -> str:
        return self.source or "grid"

    # ------------------------------------------------------------------ units
    def in_map_unit(self, values):
        """`values` in this grid's `unit` (rates, or differences of rates) in its `map_unit`."""
        return convert_rate(values, self.unit, self.map_unit, self.density_kg_l, self.seed_mass_g)

    def as_map_unit(self) -> Grid:
        """This grid with its rates in its `map_unit` (what its files are written in)."""
        if self.unit == self.map_unit:
            return self
        return replace(self, rates_kg_ha=self.in_map_unit(self.rates_kg_ha), unit=self.map_unit,
                       zone_rates_kg_ha=self._zones_converted(self.in_map_unit))

    def to_kg_ha(self, density_kg_l: float | None = None, seed_mass_g: float | None = None) -> Grid:
        """This grid with its rates in kg/ha, its `map_unit` kept to show them in.

        A volume rate needs the product's density (kg/L), a count rate the mass of one seed (g);
        without it the grid stays as it is (in its own unit; no prescription).
        """
        kind = rate_kind(self.unit)
        if self.unit == UNIT or (kind == "count" and seed_mass_g is None) or (kind == "volume" and
                                                                              density_kg_l is None):
            return self
        def to_unit(values):
            return convert_rate(values, self.unit, UNIT, density_kg_l, seed_mass_g)

        return replace(self, rates_kg_ha=to_unit(self.rates_kg_ha), unit=UNIT, map_unit=self.map_unit,
                       density_kg_l=density_kg_l, seed_mass_g=seed_mass_g,
                       zone_rates_kg_ha=self._zones_converted(to_unit))

    def _zones_converted(self, convert):
        """`zone_rates_kg_ha` through `convert` (the cells' conversion, so a zone's cells keep its rate to
        the bit); None for a raster."""
        return None if self.zone_rates_kg_ha is None else convert(self.zone_rates_kg_ha)

    # ------------------------------------------------------------------ geometry
    @property
    def rows(self) -> int:
        return self.rates_kg_ha.shape[0]

    @property
    def cols(self) -> int:
        return self.rates_kg_ha.shape[1]

    @property
    def cell_size(self) -> tuple[float, float]:
        """(x, y) size of a cell in CRS units (metres, or degrees for lon/lat grids)."""
        return (self.transform.a, -self.transform.e)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) in the grid's CRS."""
        x0, y0 = self._x0, self._y0
        return (x0, y0 - self.rows * self._dy, x0 + self.cols * self._dx, y0)

    @property
    def bounds_wgs84(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) in WGS84 degrees, densified so curved edges are enclosed."""
        if self.crs.is_geographic and self.crs == WGS84:
            return self.bounds
        from vrsim.maps.crs import transformer

        w, s, e, n = transformer(self.crs, WGS84).transform_bounds(*self.bounds, densify_pts=21)
        return (float(w), float(s), float(e), float(n))

    @property
    def cell_area_m2(self) -> float:
        """Area of one cell in m^2 (projected CRSs only)."""
        factor = metres_per_unit(self.crs)
        if factor is None:
            raise MapError(f"{self._where()}: cell area needs a projected CRS, the grid is in "
                           f"{crs_label(self.crs)} degrees; reproject it first (Grid.reproject)")
        return self._dx * self._dy * factor * factor

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """x (cols,) and y (rows,) of the cell centres, in the grid's CRS."""
        x = self._x0 + (np.arange(self.cols) + 0.5) * self._dx
        y = self._y0 - (np.arange(self.rows) + 0.5) * self._dy
        return x, y

    # ------------------------------------------------------------------ lookup
    def rate_at(self, x: float, y: float) -> float:
        """Rate (kg/ha) at one point in the grid's CRS; NaN outside or on nodata. ~1 us per call."""
        fc = (x - self._x0) * self._inv_dx
        fr = (self._y0 - y) * self._inv_dy
        # The comparisons also reject NaN coordinates (every comparison with NaN is False).
        if 0.0 <= fc < self.rates_kg_ha.shape[1] and 0.0 <= fr < self.rates_kg_ha.shape[0]:
            return float(self.rates_kg_ha[int(fr), int(fc)])
        return math.nan

    def lookup(self, x, y, crs=None, bilinear: bool = False) -> LookupResult:
        """Rates at points, vectorized.

        Parameters
        ----------
        x, y : float or array_like
            Point coordinates in `crs` (x = easting or longitude, y = northing or latitude).
        crs : pyproj.CRS or str, optional
            CRS of the points; None means the grid's CRS, ``"EPSG:4326"`` lon/lat degrees.
        bilinear : bool
            Interpolate between the four nearest cell centres instead of taking the cell's value.
            Where one of those four is nodata, the cell's own value is used; near the border the
            centres are clamped to the grid.

        Returns
        -------
        LookupResult
            Arrays of the broadcast shape of `x` and `y`.
        """
        if crs is None:
            x = np.asarray(x, dtype=np.float64)
            y = np.asarray(y, dtype=np.float64)
        else:
            x, y = transform_xy(x, y, as_crs(crs, "lookup: crs"), self.crs)
        x, y = np.broadcast_arrays(x, y)
        shape = x.shape
        x, y = x.ravel(), y.ravel()
        n = x.size
        out = LookupResult(np.empty(n), np.empty(n, dtype=bool), np.empty(n, dtype=np.int64),
                           np.empty(n, dtype=np.int64))
        # Chunks that fit in cache: the ~20 passes over the points then run at cache speed.
        for lo in range(0, n, LOOKUP_CHUNK):
            hi = min(n, lo + LOOKUP_CHUNK)
            self._lookup_chunk(x[lo:hi], y[lo:hi], bilinear, out, slice(lo, hi))
        return LookupResult(*(a.reshape(shape) for a in (out.rate_kg_ha, out.inside, out.row, out.col)))

    def _lookup_chunk(self, x, y, bilinear, out: LookupResult, sl: slice) -> None:
        fc = np.subtract(x, self._x0)
        fc *= self._inv_dx
        fr = np.subtract(self._y0, y)
        fr *= self._inv_dy
        inside = out.inside[sl]
        np.greater_equal(fc, 0.0, out=inside)
        inside &= fc < self.cols
        inside &= fr >= 0.0
        inside &= fr < self.rows
        outside = ~inside
        # Outside points (NaN included) index cell (0, 0) and are masked afterwards: one take, no
        # fancy filtering, and no cast of NaN or huge values to integers.
        fc[outside] = 0.0
        fr[outside] = 0.0
        col, row = out.col[sl], out.row[sl]
        np.copyto(col, fc, casting="unsafe")
        np.copyto(row, fr, casting="unsafe")
        flat = row * self.cols
        flat += col
        rate = out.rate_kg_ha[sl]
        self.rates_kg_ha.ravel().take(flat, out=rate)
        if bilinear:
            rate[:] = self._bilinear(fc, fr, rate)
        rate[outside] = np.nan
        row[outside] = -1
        col[outside] = -1

    def _bilinear(self, fc: np.ndarray, fr: np.ndarray, nearest: np.ndarray) -> np.ndarray:
        # Cell-centre coordinates: centre of cell c is at fc = c + 0.5.
        cx = np.clip(fc - 0.5, 0.0, self.cols - 1.0)
        cy = np.clip(fr - 0.5, 0.0, self.rows - 1.0)
        c0 = np.minimum(np.nan_to_num(cx).astype(np.int64), max(self.cols - 2, 0))
        r0 = np.minimum(np.nan_to_num(cy).astype(np.int64), max(self.rows - 2, 0))
        c1 = np.minimum(c0 + 1, self.cols - 1)
        r1 = np.minimum(r0 + 1, self.rows - 1)
        tx = np.nan_to_num(cx) - c0
        ty = np.nan_to_num(cy) - r0
        flat = self.rates_kg_ha.ravel()
        v00 = flat.take(r0 * self.cols + c0)
        v01 = flat.take(r0 * self.cols + c1)
        v10 = flat.take(r1 * self.cols + c0)
        v11 = flat.take(r1 * self.cols + c1)
        value = (v00 * (1 - tx) + v01 * tx) * (1 - ty) + (v10 * (1 - tx) + v11 * tx) * ty
        return np.where(np.isnan(value), nearest, value)

    def sample(self, *, lat=None, lon=None, x=None, y=None) -> dict:
        """The rate at one point, as the map service replies and ``vrsim map sample --json`` prints.

        Give either ``lat`` and ``lon`` (WGS84 degrees) or ``x`` and ``y`` (the grid's CRS).

        Returns
        -------
        dict
            ``{"rate_kg_ha": float or None, "inside": bool, "row": int or None, "col": int or None}``;
            rate_kg_ha is None outside the grid and on nodata cells.
        """
        geo = lat is not None or lon is not None
        proj = x is not None or y is not None
        if geo == proj or (geo and (lat is None or lon is None)) or (proj and (x is None or y is None)):
            raise MapError("sample: give either lat and lon, or x and y")
        px, py, crs = (lon, lat, WGS84) if geo else (x, y, None)
        named = (("lat", lat), ("lon", lon)) if geo else (("x", x), ("y", y))
        for name, value in named:
            check_number(value, f"sample: {name}", MapError)
        px, py = float(px), float(py)
        if crs is not None:
            # Scalar pyproj call (~5 us), not the array path: the map service answers one point.
            px, py = self._from_wgs84().transform(px, py, errcheck=False)
        fc = (px - self._x0) * self._inv_dx
        fr = (self._y0 - py) * self._inv_dy
        if not (0.0 <= fc < self.cols and 0.0 <= fr < self.rows):
            return {"rate_kg_ha": None, "inside": False, "row": None, "col": None}
        row, col = int(fr), int(fc)
        rate = float(self.rates_kg_ha[row, col])
        return {"rate_kg_ha": rate if rate == rate else None, "inside": True, "row": row, "col": col}

    def _from_wgs84(self):
        from vrsim.maps.crs import transformer

        if self._to_grid is None:
            self._to_grid = transformer(WGS84, self.crs)
        return self._to_grid

    # ------------------------------------------------------------------ summaries
    def info(self) -> dict:
        """What ``vrsim map info --json`` prints: format, CRS, bounds, cell size, size, rate stats."""
        rates = self.rates_kg_ha
        valid = int(np.count_nonzero(~np.isnan(rates)))
        has = valid > 0
        factor = metres_per_unit(self.crs)
        return {
            "source": self.source,
            "format": self.format,
            "product": self.product,
            "unit": self.unit,
            "rate_unit": self.map_unit,
            "quantity": self.quantity,
            "crs": crs_label(self.crs),
            "bounds": list(self.bounds),
            "bounds_wgs84": list(self.bounds_wgs84),
            "cell_size": list(self.cell_size),
            "cell_size_unit": "degree" if factor is None else "metre" if factor == 1.0 else
                              self.crs.axis_info[0].unit_name,
            "rows": self.rows,
            "cols": self.cols,
            **_stats(self.in_map_unit(rates), "", has),
            **(_stats(rates, "_kg_ha", has) if self.unit == UNIT else {}),
            "nodata_share": 1.0 - valid / rates.size,
        }

    # ------------------------------------------------------------------ CRS operations
    def reproject(self, dst_crs, cell_size_m: float | None = None) -> Grid:
        """This map on a north-up grid in another CRS, resampled by GDAL (`rasterio.warp.reproject`).

        A zone map (at most 64 distinct rates) is resampled nearest-neighbour (zone edges stay
        sharp); a continuous one bilinearly, or by area-weighted average onto coarser cells (see
        `maps.reproject._resampling_for`).

        Parameters
        ----------
        dst_crs : pyproj.CRS or str
            Target CRS, e.g. the field's UTM zone (`maps.utm_crs_for`).
        cell_size_m : float, optional
            Target cell size, in metres for a projected target (in degrees' equivalent metres at
            the map's centre for a geographic one). Default: the source cell size in metres.
        """
        from vrsim.maps.reproject import reproject_grid

        return reproject_grid(self, as_crs(dst_crs, "reproject: dst_crs"), cell_size_m)

    def check_overlap(self, polygon_or_bounds, crs) -> float:
        """Refuse a field that does not overlap this map.

        Parameters
        ----------
        polygon_or_bounds : shapely geometry or (minx, miny, maxx, maxy)
            The field boundary.
        crs : pyproj.CRS or str
            CRS of the field.

        Returns
        -------
        float
            The share of the field's area that the map's bounds cover, in (0, 1].

        Raises
        ------
        MapError
            If the field and the map's bounds do not overlap, or the field has no area.
        """
        from vrsim.maps.reproject import field_overlap

        return field_overlap(self, polygon_or_bounds, as_crs(crs, "check_overlap: crs"))

    def __repr__(self) -> str:
        return (f"Grid({self.rows}x{self.cols}, crs={crs_label(self.crs)!r}, cell_size={self.cell_size}, "
                f"source={self.source!r})")


DEFAULT_MAX_CELLS = 200_000_000
# Peak bytes per cell while a map is read or built: the float64 rates plus one temporary of the same
# size (a flipped, converted or rasterized copy).
READ_BYTES_PER_CELL = 16


def _stats(rates: np.ndarray, suffix: str, has: bool) -> dict:
    """min, mean and max of `rates` (NaN: nodata) as ``min_rate{suffix}`` ...; None when all nodata."""
    return {f"{name}_rate{suffix}": float(f(rates)) if has else None
            for name, f in (("min", np.nanmin), ("mean", np.nanmean), ("max", np.nanmax))}


def check_size(rows: int, cols: int, max_cells: int | None, where: str) -> None:
    """Refuse absurd grid sizes before allocating them: more than `max_cells` cells (None: no cap on
    cells, nor on bytes), or more memory than `common.files.check_grid_memory` allows."""
    if rows <= 0 or cols <= 0:
        raise MapError(f"{where}: grid size {rows} rows x {cols} columns is empty")
    if max_cells is not None and rows * cols > max_cells:
        raise MapError(f"{where}: grid of {rows} rows x {cols} columns = {rows * cols:,} cells exceeds "
                       f"the cap of {max_cells:,} cells (raise it with max_cells= / --max-cells if real)")
    files.check_grid_memory(rows, cols, READ_BYTES_PER_CELL, where, MapError,
                            max_bytes=None if max_cells is not None else math.inf)


def grid_from_bounds(bounds, cell_size, crs, rates=None, max_cells: int | None = DEFAULT_MAX_CELLS,
                     **kwargs) -> Grid:
    """A grid covering `bounds` (minx, miny, maxx, maxy) with cells of `cell_size` CRS units.

    `cell_size` is one number (square cells) or (x, y). The grid's west and north edges are at the
    bounds' minx and maxy; columns and rows are rounded up so the grid covers the bounds. `rates`
    defaults to zeros.
    """
    minx, miny, maxx, maxy = (float(v) for v in bounds)
    if not all(map(math.isfinite, (minx, miny, maxx, maxy))) or not (maxx > minx and maxy > miny):
        raise MapError(f"bounds {tuple(bounds)!r}: need finite minx < maxx and miny < maxy")
    dx, dy = (cell_size, cell_size) if np.ndim(cell_size) == 0 else cell_size
    for v in (dx, dy):
        check_positive(v, f"cell_size_m {cell_size!r}", MapError)
    cols = max(1, math.ceil((maxx - minx) / dx - 1e-9))
    rows = max(1, math.ceil((maxy - miny) / dy - 1e-9))
    check_size(rows, cols, max_cells, kwargs.get("source") or "grid")
    if rates is None:
        rates = np.zeros((rows, cols))
    return Grid(rates, Affine(float(dx), 0.0, minx, 0.0, -float(dy), maxy), crs, **kwargs)
