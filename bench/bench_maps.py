"""Map costs: vectorized and scalar lookup, loading a 10,000 x 10,000 GeoTIFF, as-applied per tick,
rasterizing many zones.

Figures
-------
map_lookup_points_per_s     Grid.lookup over 10 M points in the grid's CRS (best of 3), points/s
map_lookup_wgs84_points_per_s  the same with lon/lat points (pyproj transform included), points/s
map_rate_at_us              Grid.rate_at, scalar, per call, us
map_sample_us               Grid.sample(lat=, lon=), scalar (the map service's reply), per call, us
geotiff_10k_load_s          read_map of a 10,000 x 10,000 float32 GeoTIFF (tiled, uncompressed), s
geotiff_10k_peak_mem_ratio  peak RSS growth (VmHWM) during that load / size of the float64 rate array
geotiff_10k_deflate_load_s  the same raster DEFLATE-compressed, s
as_applied_tick_us          AsApplied.add_strips, one call with 130,000 ticks (12 m x 0.15 m strips,
                            serpentine passes on a 5 m grid), per strip, us
as_applied_tick_us_1m       the same on a 1 m grid, per strip, us
zones_50k_rasterize_s       read_map of a shapefile of 50,000 small zone polygons (pyshp-written) at 2 m, s
point_export_40k_evaluate_s read_point_log + evaluate of a zipped point shapefile of 40,000 records with
                            ISO 8601 text times (the reader's slow path; the issue's bound: 5 s), s
reproject_2k_to_wgs84_s     Grid.reproject of a 2000 x 2000 continuous map (1 m, UTM 32N) to WGS84 lon/lat
                            at 1 m (bilinear, GDAL), best of 3, s
reproject_2k_to_utm_s       the lon/lat result back to UTM 32N at 1 m, best of 3, s
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
UTM = "EPSG:32632"
N10K = 10_000


def _best(fn, repeat=3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def scalar_figures(g, x, y) -> dict[str, float]:
    calls = 200_000
    xs, ys = x[:calls].tolist(), y[:calls].tolist()
    rate_at = g.rate_at
    t0 = time.perf_counter()
    for a, b in zip(xs, ys, strict=True):
        rate_at(a, b)
    rate_at_us = (time.perf_counter() - t0) / calls * 1e6
    from vrsim.maps.crs import WGS84, transform_xy

    lon, lat = transform_xy(x[:20_000], y[:20_000], g.crs, WGS84)
    t0 = time.perf_counter()
    for a, b in zip(lon.tolist(), lat.tolist(), strict=True):
        g.sample(lat=b, lon=a)
    sample_us = (time.perf_counter() - t0) / 20_000 * 1e6
    return {"map_rate_at_us": rate_at_us, "map_sample_us": sample_us}


def _write_10k(path: str, compress: str | None) -> None:
    import rasterio
    from rasterio.windows import Window

    profile = dict(driver="GTiff", width=N10K, height=N10K, count=1, dtype="float32", crs=UTM,
                   transform=(1.0, 0.0, 500_000.0, 0.0, -1.0, 5_310_000.0), tiled=True, blockxsize=512,
                   blockysize=512, nodata=-9999.0, BIGTIFF="IF_SAFER")
    if compress:
        profile.update(compress=compress, predictor=3, num_threads="ALL_CPUS")
    rows = np.arange(1000, dtype=np.float32)[:, None]
    cols = np.arange(N10K, dtype=np.float32)[None, :]
    with rasterio.open(path, "w", **profile) as dst:
        for r0 in range(0, N10K, 1000):
            band = 100.0 + 50.0 * np.sin((rows + r0) / 300.0) * np.cos(cols / 450.0)
            dst.write(band.astype(np.float32), 1, window=Window(0, r0, N10K, 1000))


def _load_in_child(path: str) -> dict[str, float]:
    """Load in a fresh process and report its peak-RSS growth (VmHWM: ru_maxrss would carry this
    process's own peak across exec)."""
    code = (
        "import json, time\n"
        "def hwm():\n"
        "    with open('/proc/self/status') as f:\n"
        "        return next(int(ln.split()[1]) for ln in f if ln.startswith('VmHWM'))\n"
        "from vrsim import maps\nimport vrsim.maps.geotiff\n"
        "before = hwm()\n"
        "t0 = time.perf_counter()\n"
        f"g = maps.read_map({path!r}, unit='kg/ha')\n"   # the bench GeoTIFF states no unit
        "dt = time.perf_counter() - t0\n"
        "print(json.dumps({'s': dt, 'grow_kb': hwm() - before, 'bytes': g.rates_kg_ha.nbytes}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def geotiff_figures() -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="vrsim-bench-maps-") as tmp:
        plain = os.path.join(tmp, "rx10k.tif")
        _write_10k(plain, None)
        runs = [_load_in_child(plain) for _ in range(2)]
        best = min(runs, key=lambda r: r["s"])
        os.remove(plain)
        packed = os.path.join(tmp, "rx10k_deflate.tif")
        _write_10k(packed, "deflate")
        deflate = _load_in_child(packed)
    return {
        "geotiff_10k_load_s": best["s"],
        "geotiff_10k_peak_mem_ratio": max(r["grow_kb"] for r in runs) * 1024 / best["bytes"],
        "geotiff_10k_deflate_load_s": deflate["s"],
    }


def _serpentine(ticks: int, width_m: float, step_m: float, field_m: float, x0: float, y0: float):
    """`ticks` strips of serpentine passes over a square field, heading 20 degrees off the grid."""
    per_pass = int(field_m / step_m)
    k = np.arange(ticks)
    p, i = np.divmod(k, per_pass)
    along = np.where(p % 2 == 0, i, per_pass - 1 - i) * step_m
    direction = np.where(p % 2 == 0, 1.0, -1.0)
    across = (p % int(field_m / width_m) + 0.5) * width_m
    a = np.radians(20.0)
    c, s = np.cos(a), np.sin(a)
    sx = x0 + along * c - across * s
    sy = y0 + along * s + across * c
    return sx, sy, sx + direction * step_m * c, sy + direction * step_m * s


def as_applied_figures() -> dict[str, float]:
    from vrsim.maps import AsApplied, synthetic

    ticks = 130_000
    out = {}
    for cell, name in ((5.0, "as_applied_tick_us"), (1.0, "as_applied_tick_us_1m")):
        g = synthetic.uniform((500_000, 5_300_000, 501_000, 5_301_000), UTM, cell_size_m=cell)
        x0, y0, x1, y1 = _serpentine(ticks, 12.0, 0.15, 700.0, 500_300.0, 5_300_050.0)
        mass = np.full(ticks, 150.0 * 12.0 * 0.15 / 10_000)

        def once(g=g, x0=x0, y0=y0, x1=x1, y1=y1, mass=mass):
            AsApplied(g).add_strips(x0, y0, x1, y1, 12.0, mass)

        out[name] = _best(once, repeat=2) / ticks * 1e6
    return out


def zones_figures() -> dict[str, float]:
    import pyproj
    import shapefile

    from vrsim import maps

    with tempfile.TemporaryDirectory(prefix="vrsim-bench-zones-") as tmp:
        path = os.path.join(tmp, "zones")
        with shapefile.Writer(path, shapeType=shapefile.POLYGON) as w:
            w.field("RATE", "N", size=8, decimal=1)
            for i in range(50_000):
                r, c = divmod(i, 250)
                x, y = 500_000 + 7 * c, 5_300_000 - 7 * r
                w.poly([[(x, y), (x + 7, y), (x + 7, y - 7), (x, y - 7), (x, y)]])
                w.record(float(100 + i % 150))
        with open(path + ".prj", "w") as f:
            f.write(pyproj.CRS(UTM).to_wkt(version="WKT1_ESRI"))
        t0 = time.perf_counter()
        maps.read_map(path + ".shp", cell_size_m=2.0, unit="kg/ha")   # pyshp states no unit
        return {"zones_50k_rasterize_s": time.perf_counter() - t0}


def point_export_figures() -> dict[str, float]:
    import pathlib

    from tests.unit.test_evaluate import write_iso_time_export
    from vrsim.maps import read_point_log
    from vrsim.services.sim.evaluate import evaluate

    with tempfile.TemporaryDirectory(prefix="vrsim-bench-points-") as tmp:
        path, _ = write_iso_time_export(pathlib.Path(tmp), 40_000)
        t0 = time.perf_counter()
        evaluate(read_point_log(path))
        return {"point_export_40k_evaluate_s": time.perf_counter() - t0}


def reproject_figures() -> dict[str, float]:
    from vrsim.maps import synthetic

    g = synthetic.random_field((500_000, 5_300_000, 502_000, 5_302_000), UTM, cell_size_m=1.0, seed=1)
    wgs84 = g.reproject("EPSG:4326")
    return {"reproject_2k_to_wgs84_s": _best(lambda: g.reproject("EPSG:4326")),
            "reproject_2k_to_utm_s": _best(lambda: wgs84.reproject(UTM))}


def lookup_figures() -> dict[str, float]:
    from vrsim.maps import synthetic
    from vrsim.maps.crs import WGS84, transform_xy

    g = synthetic.random_field((500_000, 5_300_000, 502_000, 5_302_000), UTM, cell_size_m=1.0, seed=1)
    rng = np.random.default_rng(0)
    n = 10_000_000
    x = rng.uniform(499_900, 502_100, n)  # ~10 % of the points fall outside
    y = rng.uniform(5_299_900, 5_302_100, n)
    figures = {"map_lookup_points_per_s": n / _best(lambda: g.lookup(x, y))}
    lon, lat = transform_xy(x[:1_000_000], y[:1_000_000], g.crs, WGS84)
    figures["map_lookup_wgs84_points_per_s"] = 1_000_000 / _best(lambda: g.lookup(lon, lat, crs="EPSG:4326"))
    figures.update(scalar_figures(g, x, y))
    return figures


def run() -> dict[str, float]:
    figures = lookup_figures()
    figures.update(as_applied_figures())
    figures.update(zones_figures())
    figures.update(point_export_figures())
    figures.update(reproject_figures())
    figures.update(geotiff_figures())
    return figures


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:32} {value:,.4g}")
