"""A real-like zone prescription, made from a seed: what a John Deere Rx export of a big field looks
like, for benchmarks and tests (no real farm's file is in the repository).

Such an export is thousands of small zone polygons: cells of a regular grid (~15 m) whose corners
and edge midpoints are nudged (shared by neighbours, so the cells tile the field without gaps), cut
to the field's irregular boundary (ragged cells along it), a pond left out (a hole in the field),
a rate attribute ``rate`` of 0 or 10 (patches of each) with no unit stated, in WGS84 with a ``.prj``,
zipped. `write_zone_rx` writes one; ``invalid_ring`` turns one cell into a bow tie (a self-
intersecting ring, as exports sometimes hold) to try the repair on.
"""

from __future__ import annotations

import math
import os
import tempfile
import zipfile

import numpy as np

from vrsim.common import MapError
from vrsim.maps.crs import WGS84, as_crs, utm_crs_for
from vrsim.maps.vector import ogr

__all__ = ["write_zone_rx"]  # for benchmarks and tests: `bench/bench_real_rx.py`

RATES = (0.0, 10.0)  # the two rates of the Rx the issue tried (lb/ac, but the file does not say)


def write_zone_rx(path: str, area_ha: float = 534.0, zones: int = 22_000, seed: int = 0,
                  lon: float = 9.88, lat: float = 50.18, pond_ha: float = 0.6,
                  invalid_ring: bool = False) -> dict:
    """Write a zipped zone shapefile (``.zip``) of about `zones` polygons over about `area_ha`.

    Parameters
    ----------
    path : str
        The ``.zip`` to write (written under a temporary name beside it, then renamed).
    area_ha : float
        The field's area (the pond's included), hectares.
    zones : int
        About how many zone polygons (the grid's cells inside the field).
    seed : int
        Seeds the boundary's shape, the cells' nudges and the rate patches.
    lon, lat : float
        The field's centre, WGS84 degrees.
    pond_ha : float
        A round pond in the field with no zone (a hole in the field); 0: none.
    invalid_ring : bool
        One cell's ring crosses itself (a bow tie).

    Returns
    -------
    dict
        ``zones`` (polygons written), ``area_ha`` (their union's area in the field's UTM zone),
        ``cell_m`` (the grid's step), ``crs`` (the UTM zone's EPSG code).
    """
    import shapely

    if zones < 4 or not area_ha > 0:
        raise MapError(f"write_zone_rx: zones={zones}, area_ha={area_ha}: need at least 4 zones and an area")
    rng = np.random.default_rng(seed)
    utm = utm_crs_for(lon, lat)
    cx, cy = _to(WGS84, utm, np.array([lon]), np.array([lat]))
    boundary = _boundary(rng, float(cx[0]), float(cy[0]), area_ha * 1e4)
    cell = math.sqrt(area_ha * 1e4 / zones)
    cells, centres = _cells(rng, boundary.bounds, cell)
    cut = shapely.intersection(cells, boundary)
    keep = ~shapely.is_empty(cut) & (shapely.area(cut) > 0.01 * cell * cell)
    if pond_ha > 0:
        pond = boundary.centroid.buffer(math.sqrt(pond_ha * 1e4 / math.pi), 16)
        keep &= ~shapely.intersects(pond, shapely.points(centres))
    cut, centres = cut[keep], centres[keep]
    cut = np.array([_polygonal(g) for g in cut], dtype=object)
    rates = _patches(rng, centres, cell)
    if invalid_ring:
        cut[len(cut) // 2] = _bow_tie(cut[len(cut) // 2])
    area = shapely.union_all(shapely.make_valid(cut)).area / 1e4
    wgs = shapely.transform(cut, lambda xy: np.column_stack(_to(utm, WGS84, xy[:, 0], xy[:, 1])))
    _write_zip(path, wgs, rates)
    return {"zones": int(len(cut)), "area_ha": float(area), "cell_m": cell, "crs": utm.to_epsg()}


def _to(src, dst, x, y):
    import pyproj

    return pyproj.Transformer.from_crs(as_crs(src), as_crs(dst), always_xy=True).transform(x, y)


def _boundary(rng, cx: float, cy: float, area_m2: float):
    """An irregular field outline (a wobbly 1.3:1 oval of 40 vertices) of `area_m2`, centred at (cx, cy)."""
    import shapely

    angle = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
    radius = 1.0 + 0.08 * rng.standard_normal(angle.size).cumsum() / 4
    ring = np.column_stack((1.3 * radius * np.cos(angle), radius * np.sin(angle)))
    shape = shapely.Polygon(ring)
    scale = math.sqrt(area_m2 / shape.area)
    return shapely.Polygon(ring * scale + (cx, cy))


def _cells(rng, bounds, cell: float):
    """Grid cells over `bounds` with nudged corners and edge midpoints shared by neighbours: an array
    of 8-vertex polygons and their centres (n, 2)."""
    import shapely

    minx, miny, maxx, maxy = bounds
    nx, ny = int(math.ceil((maxx - minx) / cell)) + 1, int(math.ceil((maxy - miny) / cell)) + 1
    gx, gy = np.meshgrid(minx + cell * np.arange(nx + 1), miny + cell * np.arange(ny + 1))
    corner = np.stack((gx, gy), -1) + rng.uniform(-0.2, 0.2, (ny + 1, nx + 1, 2)) * cell
    across = corner[:, :-1] + corner[:, 1:]  # horizontal edges' midpoints, nudged north or south
    along = corner[:-1] + corner[1:]         # vertical edges' midpoints, nudged east or west
    mid_h = across / 2 + np.stack((np.zeros((ny + 1, nx)), rng.uniform(-0.1, 0.1, (ny + 1, nx)) * cell), -1)
    mid_v = along / 2 + np.stack((rng.uniform(-0.1, 0.1, (ny, nx + 1)) * cell, np.zeros((ny, nx + 1))), -1)
    ring = np.stack((corner[:-1, :-1], mid_h[:-1], corner[:-1, 1:], mid_v[:, 1:], corner[1:, 1:],
                     mid_h[1:], corner[1:, :-1], mid_v[:, :-1], corner[:-1, :-1]), axis=2)
    ring = ring.reshape(-1, 9, 2)
    return shapely.polygons(ring), ring[:, :8].mean(axis=1)


def _polygonal(geom):
    """The polygons of a cut cell (a cut can leave a line or a point beside them)."""
    import shapely

    if geom.geom_type in ("Polygon", "MultiPolygon"):
        return geom
    parts = [g for g in getattr(geom, "geoms", []) if g.geom_type == "Polygon"]
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def _patches(rng, centres: np.ndarray, cell: float) -> np.ndarray:
    """0 or 10 by patches some 20 cells across: a sum of random waves, cut at its 30th percentile."""
    field = np.zeros(len(centres))
    for _ in range(6):
        k = rng.normal(0.0, 1.0 / (20 * cell), 2)
        field += np.cos(centres @ k + rng.uniform(0, 2 * np.pi))
    return np.where(field < np.percentile(field, 30), RATES[0], RATES[1])


def _bow_tie(geom):
    """`geom`'s outline with two corners swapped: a ring that crosses itself."""
    import shapely

    polygon = geom if geom.geom_type == "Polygon" else max(geom.geoms, key=lambda g: g.area)
    xy = np.asarray(polygon.exterior.coords)[:-1]
    xy[[0, 1]] = xy[[1, 0]]
    return shapely.Polygon(xy)


def _write_zip(path: str, polygons: np.ndarray, rates: np.ndarray) -> None:
    pyogrio = ogr()
    import shapely

    from vrsim.common.written import written

    stem = os.path.basename(path).removesuffix(".zip").removesuffix(".shp")
    with tempfile.TemporaryDirectory(prefix="vrsim-rx-") as tmp, written(path, MapError) as temp:
        shp = os.path.join(tmp, stem + ".shp")
        ids = np.arange(1, len(rates) + 1, dtype=np.int32)
        pyogrio.raw.write(shp, shapely.to_wkb(polygons), [ids, rates], ["Id", "rate"],
                          driver="ESRI Shapefile", geometry_type="MultiPolygon", crs=WGS84.to_wkt(),
                          encoding="UTF-8")
        with zipfile.ZipFile(temp, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for name in sorted(os.listdir(tmp)):
                z.write(os.path.join(tmp, name), name)
