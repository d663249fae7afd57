"""Grids as point tables (one point per cell centre): GeoJSON and CSV, for as-applied maps.

Every cell is written, nodata ones with an empty (CSV) or null (GeoJSON) rate, with its row and
column, so reading the points back rebuilds the same grid. Points from other software (no row/col)
are placed on the regular lattice their coordinates imply.

GeoJSON is written in WGS84 lon/lat (RFC 7946), with the cell centres in the grid's CRS as x/y
properties; a (pre-RFC 7946) ``crs`` member in files from other software is still read. CSV carries
its CRS in a ``.prj`` file beside it (WKT, as for a shapefile), and also has lon/lat columns.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os

import numpy as np
from affine import Affine

from vrsim.common import MapError, files
from vrsim.maps.crs import WGS84, as_crs, crs_from_prj, crs_label, transform_xy
from vrsim.maps.grid import DEFAULT_MAX_CELLS, Grid, check_size
from vrsim.maps.units import map_unit, name_with_unit, unit_in_name
from vrsim.maps.zones import RATE_NAMES, geojson_crs, geojson_features

X_NAMES = ("x", "easting", "east", "e")
Y_NAMES = ("y", "northing", "north", "n")
LON_NAMES = ("lon", "longitude", "lng", "long")
LAT_NAMES = ("lat", "latitude")


def _cells(grid: Grid):
    """Flat row, col, x, y, rate of every cell, row-major."""
    rows, cols = np.divmod(np.arange(grid.rows * grid.cols), grid.cols)
    xc, yc = grid.cell_centres()
    return rows, cols, xc[cols], yc[rows], grid.rates_kg_ha.ravel()


GRID_CRS = "grid_crs"  # foreign member (RFC 7946, 6.1): the CRS of the x/y properties


def write_geojson(grid: Grid, path: str) -> None:
    """Write one Point feature per cell, in WGS84 lon/lat as RFC 7946 requires (no ``crs`` member).

    Properties: the rate named with its unit (``rate_kg_ha``; null on nodata), ``row``, ``col``,
    and the cell centre ``x``, ``y`` in the grid's own CRS, which the foreign member ``grid_crs``
    names, so vrsim reads the exact grid back while any GIS places the points right.
    """
    rows, cols, x, y, rate = _cells(grid)
    lon, lat = transform_xy(x, y, grid.crs, WGS84)
    name = name_with_unit(grid.unit)
    head = {"type": "FeatureCollection", "name": os.path.splitext(os.path.basename(path))[0],
            GRID_CRS: crs_label(grid.crs)}
    try:
        with open(path, "w") as f:
            f.write(json.dumps(head)[:-1] + ', "features": [\n')
            for i in range(rate.size):
                r = None if math.isnan(rate[i]) else float(rate[i])
                point = {"type": "Point", "coordinates": [round(float(lon[i]), 9), round(float(lat[i]), 9)]}
                props = {name: r, "row": int(rows[i]), "col": int(cols[i]), "x": float(x[i]),
                         "y": float(y[i])}
                f.write(("" if i == 0 else ",\n")
                        + json.dumps({"type": "Feature", "geometry": point, "properties": props}))
            f.write("\n]}\n")
    except OSError as exc:
        raise MapError(f"{path}: cannot write: {exc.strerror}") from None


def write_csv(grid: Grid, path: str) -> None:
    """Write ``x,y,lon,lat,row,col,rate_kg_ha`` per cell (the rate named with its unit; empty on
    nodata) and a ``.prj`` beside."""
    rows, cols, x, y, rate = _cells(grid)
    lon, lat = transform_xy(x, y, grid.crs, WGS84)
    try:
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["x", "y", "lon", "lat", "row", "col", name_with_unit(grid.unit)])
            for i in range(rate.size):
                w.writerow([repr(float(x[i])), repr(float(y[i])), f"{lon[i]:.9f}", f"{lat[i]:.9f}",
                            int(rows[i]), int(cols[i]), "" if math.isnan(rate[i]) else repr(float(rate[i]))])
        with open(os.path.splitext(path)[0] + ".prj", "w") as f:
            f.write(grid.crs.to_wkt(version="WKT1_ESRI") or grid.crs.to_wkt())
    except OSError as exc:
        raise MapError(f"{path}: cannot write: {exc.strerror}") from None


def geojson_is_points(doc: dict, path: str) -> bool:
    """True if every feature with a geometry is a Point (a point table, not rate zones)."""
    kinds = {(f.get("geometry") or {}).get("type") for f in geojson_features(doc, path)} - {None}
    return bool(kinds) and kinds == {"Point"}


def read_geojson_points(path: str, doc: dict, rate_field: str | None = None,
                        max_cells: int | None = DEFAULT_MAX_CELLS, unit: str | None = None) -> Grid:
    # A feature without geometry places no point (as for zones): leave its properties out too, so
    # rates stay paired with their coordinates.
    feats = [f for f in geojson_features(doc, path) if f.get("geometry")]
    props = [f.get("properties") or {} for f in feats]
    xy = [f["geometry"].get("coordinates") for f in feats]
    try:
        coords = np.array(xy, dtype=np.float64)[:, :2]
    except (ValueError, TypeError, IndexError):
        raise MapError(f"{path}: Point coordinates are not [x, y] numbers") from None
    table = {key: [p.get(key) for p in props] for key in set().union(*props)} if props else {}
    x, y, crs = coords[:, 0], coords[:, 1], geojson_crs(doc, path)
    if doc.get(GRID_CRS) is not None and "x" in table and "y" in table:
        # vrsim's own export: the cell centres in the grid's CRS, exactly.
        x, y = (_numbers(path, table.pop(k), k) for k in ("x", "y"))
        crs = as_crs(doc[GRID_CRS], f"{path}: {GRID_CRS}")
    return _grid_from_table(path, "geojson", x, y, table, crs, rate_field, max_cells, unit)


def read_csv(path: str, rate_field: str | None = None, crs=None,
             max_cells: int | None = DEFAULT_MAX_CELLS, unit: str | None = None) -> Grid:
    """Read a CSV point table (x/y with a .prj or `crs`, or lon/lat) into a grid."""
    data = files.read_bytes(path, "csv", MapError)
    try:
        reader = csv.DictReader(io.StringIO(data.decode("utf-8"), newline=""))
        table = {name: [] for name in reader.fieldnames or []}
        for rec in reader:
            for name in table:
                table[name].append(rec.get(name))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise MapError(f"{path}: cannot read as CSV: {exc}") from None
    lower = {k.strip().lower(): k for k in table}
    xk = next((lower[n] for n in X_NAMES if n in lower), None)
    yk = next((lower[n] for n in Y_NAMES if n in lower), None)
    if xk and yk:
        prj = os.path.splitext(path)[0] + ".prj"
        if os.path.exists(prj):
            # decoded as a shapefile's .prj is
            text = files.read_bytes(prj, "prj", MapError).decode("utf-8", "replace")
            src_crs = crs_from_prj(text, prj)
        elif crs is not None:
            src_crs = as_crs(crs, "crs")
        else:
            raise MapError(f"{path}: x/y columns but no .prj beside it: give the CRS (crs= / --crs)")
    else:
        xk = next((lower[n] for n in LON_NAMES if n in lower), None)
        yk = next((lower[n] for n in LAT_NAMES if n in lower), None)
        if not (xk and yk):
            raise MapError(f"{path}: needs x,y or lon,lat columns; has {files.shown(list(table), 200)}")
        src_crs = WGS84
    x, y = (_numbers(path, table.pop(k), k) for k in (xk, yk))
    for k in list(table):  # coordinates of the other kind (lon/lat beside x/y) are not attributes
        if k.strip().lower() in X_NAMES + Y_NAMES + LON_NAMES + LAT_NAMES:
            table.pop(k)
    return _grid_from_table(path, "csv", x, y, table, src_crs, rate_field, max_cells, unit)


def _numbers(path: str, values: list, name: str, allow_empty: bool = False) -> np.ndarray:
    out = np.empty(len(values))
    for i, v in enumerate(values):
        if allow_empty and (v is None or v == ""):
            out[i] = np.nan
            continue
        try:
            out[i] = float(v)
        except (TypeError, ValueError):
            raise MapError(f"{path}: record {i}: {name}={files.shown(v)} is not a number") from None
        if not math.isfinite(out[i]):
            raise MapError(f"{path}: record {i}: {name}={files.shown(v)} is not finite")
    return out


def _grid_from_table(path, fmt, x, y, table, crs, rate_field, max_cells, unit) -> Grid:
    if x.size == 0:
        raise MapError(f"{path}: no points")
    lower = {k.lower(): k for k in table}
    if rate_field is not None:
        if rate_field not in table:
            raise MapError(f"{path}: no attribute {rate_field!r} (rate_field); attributes: "
                           f"{files.shown(sorted(table), 200)}")
        rk = rate_field
    else:
        with_unit = [k for k in table if unit_in_name(k)]
        rk = next((lower[n] for n in RATE_NAMES if n in lower), with_unit[0] if len(with_unit) == 1 else None)
        if rk is None:
            raise MapError(f"{path}: no rate attribute among {files.shown(sorted(table), 200)}; name one "
                           "with rate_field= / --rate-field")
    rate = _numbers(path, table[rk], rk, allow_empty=True)
    if (rate < 0).any():
        i = int(np.argmax(rate < 0))
        raise MapError(f"{path}: record {i}: negative rate {rk}={files.shown(float(rate[i]))}")
    if "row" in lower and "col" in lower:
        row = _numbers(path, table[lower["row"]], "row").astype(np.int64)
        col = _numbers(path, table[lower["col"]], "col").astype(np.int64)
    else:
        row, col = _lattice_indices(path, x, y)
    if row.min() < 0 or col.min() < 0:
        raise MapError(f"{path}: negative row/col")
    rows, cols = int(row.max()) + 1, int(col.max()) + 1
    check_size(rows, cols, max_cells, path)
    dx = _spacing(col, x)
    dy = _spacing(row, y)
    dy = None if dy is None else -dy  # y falls as row rises
    if dx is None and dy is None:
        raise MapError(f"{path}: one point cannot define a cell size")
    dx, dy = dx or dy, dy or dx
    x0 = float(np.mean(x - (col + 0.5) * dx))
    y0 = float(np.mean(y + (row + 0.5) * dy))
    tol = 1e-6 * min(dx, dy)
    if np.abs(x0 + (col + 0.5) * dx - x).max() > tol or np.abs(y0 - (row + 0.5) * dy - y).max() > tol:
        raise MapError(f"{path}: the points are not the cell centres of a regular north-up grid")
    rates = np.full((rows, cols), np.nan)
    flat = row * cols + col
    if np.unique(flat).size != flat.size:
        raise MapError(f"{path}: two points for one cell")
    rates.ravel()[flat] = rate
    return Grid(rates, Affine(dx, 0.0, x0, 0.0, -dy, y0), crs, source=path, format=fmt,
                unit=map_unit(path, unit_in_name(rk), unit, f"attribute {rk!r}"))


def _spacing(index: np.ndarray, coord: np.ndarray) -> float | None:
    """Least-squares step of `coord` per unit of `index`; None if the index never changes."""
    di = index - index.mean()
    var = float(np.dot(di, di))
    if var == 0.0:
        return None
    step = float(np.dot(di, coord - coord.mean())) / var
    if not step or not math.isfinite(step):
        return None
    return step


def _lattice_indices(path: str, x: np.ndarray, y: np.ndarray):
    """Row and column of points lying on a regular lattice (smallest coordinate step = cell size)."""
    out = []
    for values, flip in ((y, True), (x, False)):
        u = np.unique(values)
        steps = np.diff(u)
        step = float(steps.min()) if steps.size else 0.0
        if step <= 0.0:
            out.append(np.zeros(values.size, dtype=np.int64))
            continue
        idx = np.rint(((u[-1] - values) if flip else (values - u[0])) / step).astype(np.int64)
        out.append(idx)
    return out[0], out[1]

