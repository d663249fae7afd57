"""Footprints: how a machine puts its product on the ground, the extension point of the deposition engine.

The engine (`maps.AsApplied`, one batch at a time; `maps.ColumnDeposit`, one geometry for many mass
columns) spreads product over a prescription's grid without knowing the machine. What it needs from
the machine is a *footprint*: a batch of items (a tick's or a strip's share of product, one each),
each turned into samples, small boxes that tile the ground the item covers. The engine splits every
sample's box between the sub-cells it overlaps (`maps.subcells`), so its accuracy follows from the
samples being no larger than the ``step`` it asks for.

A footprint kind is a class with a ``kind`` name, registered with `register_footprint`, that
implements:

``items`` (property, int)
    How many items the footprint holds; a deposit brings one mass per item (kg, or kg per column).
``samples(step, metres_per_unit, part)``
    Yields `Samples` batches covering the items of ``part`` (a slice; each item in exactly one
    batch). ``step`` is the largest side a sample's box may have, CRS units; ``metres_per_unit``
    converts lengths in metres to the grid's CRS units. The engine asks for a pass's items at a
    time (so a pass's product is on its own raster when the pass closes): an item's samples must
    not depend on the other items in ``part``.

Each item's samples tile the ground it sweeps in equal areas (``swept / samples per item``): that
is the coverage the item gives where it carries product. Its product is shared between its samples
equally, or by ``Samples.weight`` (a pattern's relative mass, summing to 1 over an item's samples).
Today's kind is `Strips` (``"section_strips"``): a rectangle per section along the track. A
spinner's 2-D pattern thrown behind the discs is a kind whose samples lie on a lattice behind and
across the disc centre with the transverse pattern's weights; a sprayer's nozzles one whose samples
are each nozzle's fan; neither needs a change to the engine. `footprint_kind` finds a kind by its
name (what a machine's configuration names); tests/unit/test_deposition.py adds a worked example, a
weighted transverse pattern, and deposits it through both modes.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from vrsim.common import MapError

MAX_SAMPLES_PER_BATCH = 4_000_000  # ~200 MB of the engine's temporaries at most


@dataclass(frozen=True)
class Samples:
    """One batch of a footprint's items as sample boxes (CRS units).

    Attributes
    ----------
    items : ndarray of int, shape (k,)
        Which of the footprint's items these are.
    x, y : ndarray, shape (k, ...)
        Each item's sample centres (the same number per item).
    ext_x, ext_y : ndarray, shape (k,) or x's shape
        Each sample box's extent along x and y.
    swept : ndarray, shape (k,)
        The area each item sweeps, shared equally between its samples.
    weight : ndarray, broadcastable to x's shape, optional
        Each sample's share of its item's product; None: equal shares.
    """

    items: np.ndarray
    x: np.ndarray
    y: np.ndarray
    ext_x: np.ndarray
    ext_y: np.ndarray
    swept: np.ndarray
    weight: np.ndarray | None = None

    @property
    def per_item(self) -> int:
        """Samples per item."""
        return int(np.prod(self.x.shape[1:], dtype=np.int64))

    def flat(self, per_item: np.ndarray) -> np.ndarray:
        """Values given per item (k,) or per sample (x's shape) as one value per sample, flat."""
        values = np.asarray(per_item)
        if values.ndim == 1:
            values = values.reshape(values.size, *(1,) * (self.x.ndim - 1))
        return np.broadcast_to(values, self.x.shape).ravel()


class Footprint(Protocol):
    """What a footprint kind implements (see the module's docstring)."""

    kind: ClassVar[str]

    @property
    def items(self) -> int: ...

    def samples(self, step: float, metres_per_unit: float, part: slice) -> Iterator[Samples]: ...


FOOTPRINTS: dict[str, type] = {}


def register_footprint(cls: type) -> type:
    """Class decorator: register a footprint kind under its ``kind`` name (each name once)."""
    kind = getattr(cls, "kind", None)
    if not isinstance(kind, str) or not kind:
        raise MapError(f"footprint {cls.__name__}: needs a class attribute 'kind', a non-empty name")
    if FOOTPRINTS.get(kind, cls) is not cls:
        raise MapError(f"footprint kind {kind!r} is registered already ({FOOTPRINTS[kind].__name__})")
    FOOTPRINTS[kind] = cls
    return cls


def footprint_kind(kind: str) -> type:
    """The footprint class registered as `kind`; `MapError` naming the known kinds otherwise."""
    if kind not in FOOTPRINTS:
        raise MapError(f"footprint kind {kind!r} is not one of {', '.join(sorted(FOOTPRINTS))}")
    return FOOTPRINTS[kind]


@register_footprint
class Strips:
    """Rectangles along the track: each item a strip of ``width_m`` across its centre line from
    (x0, y0) to (x1, y1), a section's ground over one or more ticks ("section strips").

    Parameters
    ----------
    x0, y0, x1, y1 : array_like, shape (k,)
        Start and end of each strip's centre line, in the grid's CRS.
    width_m : float or array_like, shape (k,)
        Width across the direction of travel, m (>= 0).

    A strip is cut into ``n_along x n_across`` equal sub-rectangles no longer than ``step`` on a
    side; each is a sample whose box is its axis-aligned bounding box. Along the grid's axes the
    boxes are exact; obliquely they smear by up to ``step`` across a cell edge (below 0.5 % per cell
    at any heading, `maps.AsApplied`). A zero-length strip puts its product at its point and sweeps
    no area.
    """

    kind = "section_strips"

    def __init__(self, x0, y0, x1, y1, width_m):
        x0, y0, x1, y1, width = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64).ravel()
                                                      for v in (x0, y0, x1, y1, width_m)))
        bad = ~(np.isfinite(x0) & np.isfinite(y0) & np.isfinite(x1) & np.isfinite(y1))
        if bad.any():
            raise MapError(f"add_strips: strip {int(np.argmax(bad))} has a non-finite coordinate")
        if not np.all(np.isfinite(width) & (width >= 0)):
            i = int(np.argmax(~(np.isfinite(width) & (width >= 0))))
            raise MapError(f"add_strips: width_m[{i}]={width[i]!r} must be finite and >= 0")
        self.x0, self.y0, self.x1, self.y1, self.width_m = x0, y0, x1, y1, width

    @property
    def items(self) -> int:
        return self.x0.size

    def samples(self, step: float, metres_per_unit: float, part: slice) -> Iterator[Samples]:
        """The strips of `part` in batches of one sampling pattern (strips cut alike), at most
        `MAX_SAMPLES_PER_BATCH` samples each."""
        first = part.indices(self.items)[0]
        x0, y0 = self.x0[part], self.y0[part]
        width = self.width_m[part] / metres_per_unit  # width like the coordinates
        dx, dy = self.x1[part] - x0, self.y1[part] - y0
        length = np.hypot(dx, dy)
        n_al = np.maximum(1, np.ceil(length / step)).astype(np.int64)
        n_ac = np.maximum(1, np.ceil(width / step)).astype(np.int64)
        # Strips cut alike are done together as (k, n_al, n_ac) arrays; a run has one or a few
        # patterns (short ticks: n_al = 1; one working width).
        key = n_al * (int(n_ac.max(initial=0)) + 1) + n_ac
        if key.size and (key == key[0]).all():
            patterns, group = key[:1], None  # the usual case: skip the sort
        else:
            patterns, group = np.unique(key, return_inverse=True)
        for g, k in enumerate(patterns):
            idx = np.arange(key.size) if group is None else np.flatnonzero(group == g)
            nal, nac = divmod(int(k), int(n_ac.max()) + 1)
            per_chunk = max(1, MAX_SAMPLES_PER_BATCH // int(nal * nac))
            for lo in range(0, idx.size, per_chunk):
                sel = idx[lo:lo + per_chunk]
                yield _strip_samples(first + sel, x0[sel], y0[sel], dx[sel], dy[sel], length[sel], width[sel],
                                     nal, nac)


_PER_STRIP = (slice(None), None, None)  # per-strip values broadcast over (n_al, n_ac)


def _strip_samples(sel, x0, y0, dx, dy, length, width, nal: int, nac: int) -> Samples:
    """Centres (k, n_al, n_ac) of each strip's sub-rectangles, their axis-aligned extent (k,) and the
    strip's swept area (k,), CRS units."""
    col = _PER_STRIP
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(length > 0, 1.0 / length, 0.0)
    cos, sin = dx * inv, dy * inv
    # Sub-rectangle centres: u along in (0, 1), v across in (-1/2, 1/2); across = left normal.
    u = ((np.arange(nal) + 0.5) / nal)[None, :, None]
    v = ((np.arange(nac) + 0.5) / nac - 0.5)[None, None, :]
    x = x0[col] + u * dx[col] - v * (width * sin)[col]
    y = y0[col] + u * dy[col] + v * (width * cos)[col]
    # Axis-aligned extent of each sub-rectangle, for spreading it over the sub-cells it overlaps.
    a_al, a_ac = length / nal, width / nac
    ext_x = np.abs(cos) * a_al + np.abs(sin) * a_ac
    ext_y = np.abs(sin) * a_al + np.abs(cos) * a_ac
    return Samples(sel, x, y, ext_x, ext_y, a_al * a_ac * nal * nac)
