"""Vectorized polygon rasterization (scan lines, even-odd rule) for rate-zone maps.

Polygons are given as rings: vertex arrays `x`, `y` concatenated, `ring_start` (R + 1 offsets) and
`ring_owner` (the polygon, i.e. feature, of each ring). Holes and multi-part polygons need no
special treatment: under the even-odd rule a point is inside a feature when a ray from it crosses
the feature's rings an odd number of times.

A cell belongs to a feature when its centre is inside (the rule GDAL's rasterizer uses); where
features overlap, the later one wins (`rasterize_rings`), or the union is marked (`fill_rings`).
Cost: ~O(edges x rows they span + covered cells), all in numpy; no per-polygon Python.
"""

from __future__ import annotations

import numpy as np

FILL_CHUNK = 4_000_000  # cells written per pass: bounds the temporaries
# `fill_rings` writes a span at least this many cells long as a slice (about a microsecond of Python
# each), shorter ones through their cells' indices (about 10 ns a cell): a field's rows are a few long
# spans, a coverage map's landed strips many short ones.
LONG_SPAN = 64


def rasterize_rings(x: np.ndarray, y: np.ndarray, ring_start: np.ndarray, ring_owner: np.ndarray,
                    west: float, north: float, size: float, rows: int, cols: int) -> np.ndarray:
    """Feature index of each cell (-1 where none), shape (rows, cols).

    Parameters
    ----------
    x, y : ndarray, shape (v,)
        Vertices of all rings, concatenated. Rings may be closed (last = first) or not.
    ring_start : ndarray of int, shape (r + 1,)
        Ring k is vertices ``ring_start[k]:ring_start[k + 1]``.
    ring_owner : ndarray of int, shape (r,)
        Feature index of each ring (0-based; later features win overlaps).
    west, north, size : float
        Grid origin (north-west corner) and square cell size, in the vertices' units.
    rows, cols : int
        Grid shape.
    """
    out = np.full((rows, cols), -1, dtype=np.int32)
    srow, c0, c1, sown = _ring_spans(x, y, ring_start, ring_owner, west, north, size, rows, cols)
    if srow.size:
        _fill(out, srow, c0, c1, sown, _overlapping(srow, c0, c1))
    return out


def fill_rings(out: np.ndarray, x: np.ndarray, y: np.ndarray, ring_start: np.ndarray,
               ring_owner: np.ndarray, west: float, north: float, size: float, value=True) -> None:
    """OR `value` into the cells of `out` (rows, cols; bool or integer, contiguous) whose centre is
    inside any feature, in place; the other arguments are those of `rasterize_rings`."""
    rows, cols = out.shape
    srow, c0, c1, _ = _ring_spans(x, y, ring_start, ring_owner, west, north, size, rows, cols)
    flat = out.reshape(-1)  # a view
    long = c1 - c0 >= LONG_SPAN   # (an OR: the order the cells are written in changes nothing)
    first = srow[long] * cols + c0[long]
    for a, b in zip(first.tolist(), (first + (c1 - c0)[long]).tolist(), strict=True):
        flat[a:b] |= value
    short = ~long
    for idx, _, _ in _span_cells(srow[short], c0[short], c1[short], cols):
        flat[idx] |= value


def _ring_spans(x, y, ring_start, ring_owner, west, north, size, rows, cols):
    """Row spans of cells whose centre lies inside each feature (even-odd rule over its rings).

    Arguments as `rasterize_rings`. Returns ``(row, c0, c1, owner)``, int arrays of one entry per
    span, in the order of (owner, row, c0): cells ``c0 <= col < c1`` of ``row`` belong to feature
    ``owner``; empty spans are left out.
    """
    nxt, owner = _edges(ring_start, ring_owner, x.size)
    row, xc, owner = _crossings(x, y, nxt, owner, north, size, rows)
    if row.size == 0:
        empty = np.empty(0, dtype=np.int64)
        return empty, empty, empty, empty
    xc, row, owner = _by_feature_row_x(xc, row, owner, rows)
    # Inside each (feature, row) the crossings, ordered by x, pair up as spans.
    x0, x1, srow, sown = xc[0::2], xc[1::2], row[0::2], owner[0::2]
    # Columns whose centre lies in [x0, x1).
    c0 = np.clip(np.ceil((x0 - west) / size - 0.5), 0, cols).astype(np.int64)
    c1 = np.clip(np.ceil((x1 - west) / size - 0.5), 0, cols).astype(np.int64)
    keep = c1 > c0
    return srow[keep], c0[keep], c1[keep], sown[keep]


def _by_feature_row_x(xc, row, owner, rows):
    """The crossings sorted by (feature, row, x).

    Crossings come ring by ring, edge by edge, so (feature, row) is mostly in order already: a
    stable sort on it alone is nearly linear. Most (feature, row) hold one pair, ordered by min and
    max; only the larger groups (rings folding over a row) are sorted by x.
    """
    key = owner.astype(np.int64) * rows + row   # int64: features x rows may pass 2**31
    order = np.argsort(key, kind="stable")
    key, xc, row, owner = key[order], xc[order], row[order], owner[order]
    bounds = np.flatnonzero(np.diff(key)) + 1
    sizes = np.diff(np.concatenate(([0], bounds, [key.size])))
    if (sizes > 2).any():
        members = np.flatnonzero(np.repeat(sizes > 2, sizes))
        xc[members] = xc[members[np.lexsort((xc[members], key[members]))]]
    first, second = xc[0::2], xc[1::2]
    xc[0::2], xc[1::2] = np.minimum(first, second), np.maximum(first, second)
    return xc, row, owner


def _overlapping(row, c0, c1) -> bool:
    """Whether any two spans share a cell (sorted by row and start, a span overlaps the next)."""
    order = np.lexsort((c0, row))
    r, a, b = row[order], c0[order], c1[order]
    return bool(((r[1:] == r[:-1]) & (a[1:] < b[:-1])).any())


def _edges(ring_start, ring_owner, n):
    """Every ring edge, closing edges included (a degenerate one for an already closed ring), of `n`
    vertices: the index of each vertex's next one along its ring, and its feature."""
    nxt = np.arange(1, n + 1)
    ends = ring_start[1:] - 1
    nxt[ends] = ring_start[:-1]  # the last vertex of a ring connects back to its first
    owner = np.repeat(ring_owner, np.diff(ring_start))
    return nxt, owner


def _crossings(x, y, nxt, owner, north, size, rows):
    """(row, x, feature) where each non-horizontal edge (vertex to `nxt`) crosses a row's centre line.

    Half-open in y (ymin <= yc < ymax) so a vertex shared by two edges counts once.
    """
    # Row r's centre is at fy = r, with fy(y) = (north - y) / size - 0.5, which falls as y rises: the
    # rows an edge crosses run from after fy(ymax)'s floor to fy(ymin)'s, each floor taken per vertex.
    fy = np.floor((north - y) / size - 0.5).astype(np.int64)
    fa, fb = fy, fy[nxt]
    r_lo = np.maximum(np.minimum(fa, fb) + 1, 0)
    r_hi = np.minimum(np.maximum(fa, fb), rows - 1)
    count = r_hi - r_lo + 1   # none for a horizontal edge (equal floors)
    edge = np.flatnonzero(count > 0)
    count, r_lo = count[edge], r_lo[edge]
    first = np.cumsum(count) - count
    row = np.repeat(r_lo - first, count) + np.arange(int(first[-1] + count[-1]) if edge.size else 0)
    yc = north - (row + 0.5) * size
    ya, xa, end = y[edge], x[edge], nxt[edge]
    t = (yc - np.repeat(ya, count)) / np.repeat(y[end] - ya, count)
    xc = np.repeat(xa, count) + t * np.repeat(x[end] - xa, count)
    # An edge that crosses a row centre exactly at a row outside the grid was clipped on both
    # ends, so crossings come in pairs per (feature, row) as long as each ring is a closed loop.
    return row, xc, np.repeat(owner[edge], count)


def _span_cells(row, c0, c1, cols):
    """Flat cell indices of spans [c0, c1) of `row`, in chunks of at most ~`FILL_CHUNK` cells:
    yields (indices, lo, hi), the chunk holding spans lo .. hi - 1."""
    length = c1 - c0
    ends = np.cumsum(length)
    lo = 0
    while lo < length.size:
        base = ends[lo - 1] if lo else 0
        hi = max(lo + 1, int(np.searchsorted(ends, base + FILL_CHUNK, side="right")))
        ln = length[lo:hi]
        # A span's cells are its first cell's index plus 0, 1, ...: the running count less its start.
        first = row[lo:hi] * cols + c0[lo:hi] - (ends[lo:hi] - ln - base)
        yield np.repeat(first, ln) + np.arange(ends[hi - 1] - base), lo, hi
        lo = hi


def _fill(out: np.ndarray, row, c0, c1, owner, overlapping: bool) -> None:
    """Write spans [c0, c1) of `row` with their feature (later features win)."""
    flat = out.ravel()
    for idx, lo, hi in _span_cells(row, c0, c1, out.shape[1]):
        value = np.repeat(owner[lo:hi].astype(np.int32), c1[lo:hi] - c0[lo:hi])
        # Later features have higher indices. Overlaps are rare: only then pay for maximum.at, which
        # makes "later wins" exact whatever order numpy would write duplicates in.
        if overlapping:
            np.maximum.at(flat, idx, value)
        else:
            flat[idx] = value
