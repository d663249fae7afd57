"""The scan-line polygon rasterizer against GDAL's (rasterio.features.rasterize) on random shapes."""

import numpy as np
import pytest
import shapely
from affine import Affine
from rasterio.features import rasterize

from vrsim.maps.rasterize import fill_rings, rasterize_rings
from vrsim.maps.zones import _Rings


def rings_of(geoms):
    """Rings (exterior and holes) of shapely polygons/multipolygons, owner = position in `geoms`."""
    rings, owners = [], []
    for i, g in enumerate(geoms):
        for poly in getattr(g, "geoms", [g]):
            for ring in [poly.exterior, *poly.interiors]:
                rings.append(np.asarray(ring.coords))
                owners.append(i)
    return _Rings.from_lists(rings, owners)


def star(rng, cx, cy, r, n=9):
    """A random concave star polygon."""
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = r * rng.uniform(0.3, 1.0, n)
    return shapely.Polygon(np.column_stack((cx + rad * np.cos(a), cy + rad * np.sin(a))))


@pytest.mark.parametrize("seed", range(4))
def test_matches_gdal_on_random_polygons_with_holes_and_parts(seed):
    rng = np.random.default_rng(seed)
    geoms = []
    for _ in range(30):
        cx, cy = rng.uniform(10, 90, 2)
        poly = star(rng, cx, cy, rng.uniform(3, 15))
        if rng.random() < 0.4:  # a hole
            poly = poly.difference(shapely.Point(cx, cy).buffer(rng.uniform(0.5, 2.5)))
        if rng.random() < 0.3:  # a second part
            poly = poly.union(star(rng, cx + 20, cy - 10, 4))
        if not poly.is_empty:
            geoms.append(poly)
    west, north, size, rows, cols = 0.0, 100.0, 0.37, 270, 270
    ours = rasterize_rings(*_args(rings_of(geoms)), west, north, size, rows, cols)
    gdal = rasterize(zip(geoms, range(len(geoms)), strict=True), out_shape=(rows, cols), fill=-1,
                     transform=Affine(size, 0, west, 0, -size, north), dtype="int32")
    # Identical but for cells whose centre lies within rounding of an edge (none, or a handful).
    assert (ours != gdal).sum() <= 3


def _args(r):
    return r.x, r.y, r.ring_start, r.ring_owner


def test_square_exact_and_unclosed_ring():
    # A 4 x 4 square with corners on cell edges: exactly 16 cells, whether the ring is closed or not.
    for ring in ([(1, 1), (5, 1), (5, 5), (1, 5), (1, 1)], [(1, 1), (5, 1), (5, 5), (1, 5)]):
        out = rasterize_rings(*_args(_Rings.from_lists([np.array(ring, float)], [0])), 0.0, 6.0, 1.0, 6, 6)
        assert (out == 0).sum() == 16 and (out[1:5, 1:5] == 0).all()


def test_later_feature_wins_overlap():
    a = np.array([(0, 0), (4, 0), (4, 4), (0, 4)], float)
    b = a + 2.0
    out = rasterize_rings(*_args(_Rings.from_lists([a, b], [0, 1])), 0.0, 6.0, 1.0, 6, 6)
    assert out[2, 2] == 1 and out[5, 0] == 0 and out[0, 5] == 1 and out[0, 0] == -1


def test_polygon_outside_or_partly_outside_grid():
    ring = np.array([(-5, -5), (3, -5), (3, 3), (-5, 3)], float)
    out = rasterize_rings(*_args(_Rings.from_lists([ring], [0])), 0.0, 6.0, 1.0, 6, 6)
    assert (out == 0).sum() == 9 and (out[3:, :3] == 0).all()
    far = np.array([(50, 50), (60, 50), (60, 60)], float)
    out = rasterize_rings(*_args(_Rings.from_lists([far], [0])), 0.0, 6.0, 1.0, 6, 6)
    assert (out == -1).all()


def test_fill_rings_is_the_union_and_ors_a_value():
    rng = np.random.default_rng(5)
    geoms = [star(rng, *rng.uniform(10, 90, 2), rng.uniform(3, 15)) for _ in range(20)]
    rings = rings_of(geoms)
    owners = rasterize_rings(*_args(rings), 0.0, 100.0, 0.5, 200, 200)
    mask = np.zeros((200, 200), bool)
    fill_rings(mask, *_args(rings), 0.0, 100.0, 0.5)
    # Later features win in `rasterize_rings`, so every covered cell has some owner there too.
    assert mask.any() and np.array_equal(mask, owners >= 0)
    bits = np.full((200, 200), 2, np.uint8)
    fill_rings(bits, *_args(rings), 0.0, 100.0, 0.5, value=1)
    assert np.array_equal(bits, np.where(mask, 3, 2))
