"""A spinner spreader's footprint: each disc's tick of product thrown behind it across its half of the
spread width, weighted by the transverse pattern (a footprint kind of `maps.footprint`).

Each item is one disc's product over one tick: the disc centre travels from (x0, y0) to (x1, y1); the
product lands ``throw_distance_m`` behind it (along that travel), across the disc's side of the centre
line (``side`` +1: left of travel, -1: right) out to the item's ``reach_m`` (the side's cut: border
spreading, a shortened spread width; at most the pattern's extent on that side). Samples lie on a
lattice of ``n_along x n_across`` boxes tiling that ground; a sample's weight is the pattern's mass
over its strip of offsets, exact for the pattern's piecewise-linear density, renormalized over the
reach (a cut side puts its whole product inside its cut). A zero-length item (no direction) puts its
product at its disc centre and sweeps no area, as a zero-length `maps.Strips` strip does.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from vrsim.common import MapError
from vrsim.common.pattern_integral import cumulative_mass
from vrsim.maps.footprint import MAX_SAMPLES_PER_BATCH, Samples, register_footprint


@register_footprint
class SpinnerThrow:
    """Spinner discs' ticks of product thrown behind them ("spinner").

    Parameters
    ----------
    x0, y0, x1, y1 : array_like, shape (k,)
        Each disc centre's travel over its tick, in the grid's CRS.
    side : array_like of int, shape (k,)
        +1: the left disc (throws left of travel), -1: the right disc.
    reach_m : array_like, shape (k,)
        How far across its side each item throws, m (> 0; cut at the pattern's extent on that side).
    offset_m, mass_per_m : array_like, shape (n,)
        The transverse pattern's knots (lateral offset, m, increasing, positive to the left) and its
        relative mass per metre there (>= 0): linear between knots, zero beyond.
    throw_distance_m : float
        How far behind the disc centre the product lands, m (>= 0).
    """

    kind = "spinner"

    def __init__(self, x0, y0, x1, y1, side, reach_m, offset_m, mass_per_m, throw_distance_m: float = 0.0):
        x0, y0, x1, y1, side, reach = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64).ravel()
                                                            for v in (x0, y0, x1, y1, side, reach_m)))
        if not np.all(np.isfinite(x0) & np.isfinite(y0) & np.isfinite(x1) & np.isfinite(y1)):
            raise MapError("SpinnerThrow: an item has a non-finite coordinate")
        if not np.all(np.abs(side) == 1):
            raise MapError("SpinnerThrow: side must be +1 (left disc) or -1 (right disc)")
        if not np.all(np.isfinite(reach) & (reach > 0)):
            i = int(np.argmax(~(np.isfinite(reach) & (reach > 0))))
            raise MapError(f"SpinnerThrow: reach_m[{i}]={reach[i]:g} must be finite and > 0 (a side that "
                           "is off carries no product)")
        if not (np.isfinite(throw_distance_m) and throw_distance_m >= 0):
            raise MapError(f"SpinnerThrow: throw_distance_m={throw_distance_m!r} must be finite and >= 0")
        self._knots = _checked_knots(offset_m, mass_per_m)
        extent = np.where(side > 0, self._knots[0][-1], -self._knots[0][0])
        self.reach_m = np.minimum(reach, np.maximum(extent, 0.0))
        knots = self._knots
        centre = cumulative_mass(*knots, np.zeros_like(side))
        total = np.abs(cumulative_mass(*knots, side * self.reach_m) - centre)
        if not np.all(total > 0):
            i = int(np.argmax(~(total > 0)))
            raise MapError(f"SpinnerThrow: item {i} throws nothing: the pattern holds no mass within its "
                           f"reach {reach[i]:g} m on its side")
        self.x0, self.y0, self.x1, self.y1, self.side = x0, y0, x1, y1, side
        self.throw_distance_m = float(throw_distance_m)
        self._half_m = float(max(self._knots[0][-1], -self._knots[0][0]))  # the lattice's full reach

    @property
    def items(self) -> int:
        return self.x0.size

    def samples(self, step: float, metres_per_unit: float, part: slice) -> Iterator[Samples]:
        """The items of `part` in batches of one lattice (items of one travel length cut alike), at
        most `MAX_SAMPLES_PER_BATCH` samples each."""
        first = part.indices(self.items)[0]
        dx, dy = self.x1[part] - self.x0[part], self.y1[part] - self.y0[part]
        length = np.hypot(dx, dy)
        # Across: one count for every item (it depends on the pattern, not on `part`), fine enough for
        # the widest reach.
        n_ac = max(1, int(np.ceil(self._half_m / metres_per_unit / step)))
        n_al = np.maximum(1, np.ceil(length / step)).astype(np.int64)
        counts, group = np.unique(n_al, return_inverse=True)
        for g, nal in enumerate(counts):
            idx = np.flatnonzero(group == g)
            per_chunk = max(1, MAX_SAMPLES_PER_BATCH // int(nal * n_ac))
            for lo in range(0, idx.size, per_chunk):
                sel = idx[lo:lo + per_chunk]
                yield self._lattice(first + sel, int(nal), n_ac, metres_per_unit)

    def _lattice(self, items: np.ndarray, nal: int, nac: int, metres_per_unit: float) -> Samples:
        """Samples (k, n_al, n_ac) of `items`: centres, axis-aligned extents, swept areas, weights."""
        x0, y0, side = self.x0[items], self.y0[items], self.side[items]
        dx, dy = self.x1[items] - x0, self.y1[items] - y0
        length = np.hypot(dx, dy)
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(length > 0, 1.0 / length, 0.0)
        cos, sin = dx * inv, dy * inv
        reach = self.reach_m[items]
        throw = self.throw_distance_m / metres_per_unit
        # Across: the disc's side out to its reach, in `nac` strips; along: the tick in `nal` pieces,
        # shifted back by the throw. Across is the left normal (-sin, cos), signed by the side.
        u = ((np.arange(nal) + 0.5) / nal)[None, :, None]
        frac = np.arange(nac + 1) / nac
        across = (side * reach / metres_per_unit)[:, None] * ((frac[:-1] + frac[1:]) / 2)[None, :]
        col = (slice(None), None, None)
        x = (x0 - throw * cos)[col] + u * dx[col] - across[:, None, :] * sin[col]
        y = (y0 - throw * sin)[col] + u * dy[col] + across[:, None, :] * cos[col]
        # Each strip's weight: the pattern's mass over its offsets, over the whole reach's.
        edges = cumulative_mass(*self._knots, (side * reach)[:, None] * frac[None, :])
        weight = np.abs(np.diff(edges, axis=1)) / np.abs(edges[:, -1] - edges[:, 0])[:, None]
        a_al, a_ac = length / nal, reach / metres_per_unit / nac
        ext_x = np.abs(cos) * a_al + np.abs(sin) * a_ac
        ext_y = np.abs(sin) * a_al + np.abs(cos) * a_ac
        return Samples(items, x, y, ext_x, ext_y, length * reach / metres_per_unit,
                       weight[:, None, :] / nal)


def _checked_knots(offset_m, mass_per_m) -> tuple[np.ndarray, np.ndarray]:
    """The pattern's knots as float arrays; `MapError` unless offsets increase and masses are >= 0."""
    xs, ms = np.asarray(offset_m, dtype=float).ravel(), np.asarray(mass_per_m, dtype=float).ravel()
    if xs.size < 2 or xs.size != ms.size:
        raise MapError(f"SpinnerThrow: the pattern needs >= 2 knots of (offset_m, mass_per_m), got "
                       f"{xs.size} and {ms.size}")
    if not (np.all(np.isfinite(xs)) and np.all(np.diff(xs) > 0)):
        raise MapError("SpinnerThrow: the pattern's offset_m must be finite and increasing")
    if not np.all(np.isfinite(ms) & (ms >= 0)):
        raise MapError("SpinnerThrow: the pattern's mass_per_m must be finite and >= 0")
    return xs, ms
