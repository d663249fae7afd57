"""GeoTIFF prescription maps, via rasterio (the GTiff driver only)."""

from __future__ import annotations

import os
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import rasterio
from rasterio.errors import RasterioError
from rasterio.windows import Window

from vrsim.common import MapError, files
from vrsim.maps.crs import as_crs
from vrsim.maps.grid import DEFAULT_MAX_CELLS, Grid, check_size
from vrsim.maps.units import map_unit
from vrsim.maps.warn import MapWarning

NODATA_OUT = -9999.0
# GDAL's block cache defaults to 5 % of RAM; reading straight into our array needs none, and a big
# cache would double the peak memory of a large read. No side files, VRT sources or network
# (`common.files.GDAL_READ_ENV`).
_READ_ENV = {"GDAL_CACHEMAX": 16, **files.GDAL_READ_ENV}
# The GDAL driver a raster map is opened with: vrsim reads GeoTIFF only (a VRT, or any other format,
# under a .tif name is refused, not opened).
DRIVER = "GTiff"


def read_geotiff(path: str, crs=None, max_cells: int | None = DEFAULT_MAX_CELLS,
                 unit: str | None = None) -> Grid:
    """Read band 1 of a raster as rates in the unit it states (or `unit`).

    Parameters
    ----------
    path : str
        The raster file.
    crs : pyproj.CRS or str, optional
        Used only when the file has no CRS.
    max_cells : int or None
        Refuse rasters with more cells than this.
    unit : str, optional
        The rates' unit (`maps.units.rate_unit`), over what the file states: band 1's unit, else
        its ``unit`` tag (dataset or band, as vrsim writes them). Neither stated nor given: refused.

    Notes
    -----
    The band is read by GDAL directly into a float64 array (no intermediate copy), in bands of
    rows on up to 4 threads; the nodata value becomes NaN. NaN cells are nodata when the file
    declares no nodata value or NaN; with another nodata value they are refused, as are negative
    rates, unless the raster says it holds differences of rates (tag ``quantity=difference``, as
    vrsim writes ``error.tif``, or a band description with "difference" in it): then the grid's
    `quantity` is ``"difference"``. The file and the files GDAL may open beside it must be regular
    files within their byte caps (`common.files`). The file must be a TIFF, opened with the GTiff
    driver only, without its side files (``.aux.xml``, ``.ovr``), VRT sources or network access; a
    ``/vsi...`` path is refused.
    """
    real = files.gdal_path(path, MapError)
    files.check_file(path, "geotiff", MapError)
    files.check_siblings(path, MapError)
    if files.head_bytes(path, 4, MapError) not in files.TIFF_SIGNATURES:
        raise MapError(f"{path}: cannot read as a raster: not a GeoTIFF (no TIFF header); vrsim reads "
                       ".tif files as GeoTIFF only, not a GDAL VRT or another format under that name")
    try:
        with rasterio.Env(**_READ_ENV), rasterio.open(real, driver=DRIVER) as src:
            check_size(src.height, src.width, max_cells, path)
            if src.count > 1:
                warnings.warn(f"{path}: {src.count} bands; reading band 1 as the rate", MapWarning,
                              stacklevel=2)
            if src.crs is None and crs is None:
                raise MapError(f"{path}: the raster has no CRS; give one (crs= / --crs)")
            grid_crs = as_crs(src.crs.to_wkt(), f"{path}: CRS") if src.crs is not None else as_crs(crs, "crs")
            nodata, transform, tags = src.nodata, src.transform, src.tags()
            stated, key = _stated_unit(src)
            unit = map_unit(path, stated, unit, key)
            quantity = _quantity(tags, src.descriptions[0])
            rates = np.empty((src.height, src.width), dtype=np.float64)
            bands = [(r0, min(src.height, r0 + BAND_ROWS)) for r0 in range(0, src.height, BAND_ROWS)]
            if len(bands) == 1:
                checks = [_read_band(src, rates, bands[0], nodata)]
            else:
                checks = _read_parallel(real, rates, bands, nodata)
    except RasterioError as exc:
        raise MapError(f"{path}: cannot read as a raster: {exc}") from None
    for r0, nan_found, low in checks:
        if nan_found:
            raise MapError(f"{path}: NaN rates in cells that are not nodata (nodata is {nodata}), "
                           f"from row {r0}")
        if low < 0 and quantity == "rate":
            row, col = np.argwhere(rates < 0)[0]
            raise MapError(f"{path}: negative rate {files.shown(float(rates[row, col]))} {unit} at row "
                           f"{row}, column {col}")
    return Grid(rates, transform, grid_crs, product=tags.get("product", ""), source=path, format="geotiff",
                quantity=quantity, unit=unit)


def _stated_unit(src) -> tuple[str | None, str]:
    """(the rate unit the raster states, where): band 1's unit, else a ``unit`` tag of band 1 or of
    the dataset; (None, "") when it states none."""
    for key, value in (("band unit", (src.units or ("",))[0]), ("band tag unit", src.tags(1).get("unit")),
                       ("tag unit", src.tags().get("unit"))):
        if value:
            return value, key
    return None, ""


def _quantity(tags: dict, description: str | None) -> str:
    """``"difference"`` when the raster says it holds signed differences of rates, else ``"rate"``."""
    if tags.get("quantity") == "difference" or "difference" in (description or "").lower():
        return "difference"
    return "rate"


BAND_ROWS = 256  # rows per read: a few MB, so the checks run on data still in cache


def _read_band(src, rates: np.ndarray, band: tuple[int, int], nodata) -> tuple[int, bool, float]:
    """Read rows [r0, r1) of band 1 straight into `rates` (GDAL converts to float64), turn nodata
    into NaN, and return (r0, NaN found that is not nodata, minimum rate)."""
    r0, r1 = band
    out = rates[r0:r1]
    src.read(1, window=Window(0, r0, rates.shape[1], r1 - r0), out=out)
    nan_found = False
    if nodata is not None and not np.isnan(nodata):
        nan_found = bool(np.isnan(out).any())
        out[out == nodata] = np.nan
    # fmin skips NaN; an all-NaN band gives NaN, which compares False below.
    return r0, nan_found, float(np.fmin.reduce(out, axis=None))


def _read_parallel(path: str, rates: np.ndarray, bands: list, nodata) -> list:
    """Read bands on a few threads, each with its own dataset (GDAL releases the GIL while reading)."""
    workers = max(1, min(4, os.cpu_count() or 1))

    def work(part):
        with rasterio.Env(**_READ_ENV), rasterio.open(path, driver=DRIVER) as src:
            return [_read_band(src, rates, band, nodata) for band in part]

    with ThreadPoolExecutor(max_workers=workers) as pool:
        parts = pool.map(work, [bands[i::workers] for i in range(workers)])
        return [check for part in parts for check in part]


# Band descriptions (what GIS tools show as the band's name) when the grid names no product.
DESCRIPTIONS = {"rate": "application rate", "difference": "rate difference"}


def write_geotiff(grid: Grid, path: str) -> None:
    """Write a grid as a tiled, DEFLATE-compressed float32 GeoTIFF.

    float32 holds a rate to 7 significant digits (0.001 kg/ha at 10,000 kg/ha), and halves the file
    of float64. nodata cells are written as -9999 with that declared as the nodata value, so QGIS and
    farm software that do not handle NaN show them as empty. The band's description is the product
    (or "application rate" / "rate difference") and its unit the grid's; the dataset tags ``product``,
    ``unit`` and ``quantity`` (``rate`` or ``difference``) let vrsim read it back for what it is.
    """
    rates = grid.rates_kg_ha
    data = np.where(np.isnan(rates), NODATA_OUT, rates).astype(np.float32)
    profile = dict(driver="GTiff", width=grid.cols, height=grid.rows, count=1, dtype="float32",
                   crs=grid.crs.to_wkt(), transform=grid.transform, nodata=NODATA_OUT, compress="deflate",
                   predictor=3)
    if grid.rows >= 256 and grid.cols >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    try:
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(data, 1)
            dst.update_tags(product=grid.product, unit=grid.unit, quantity=grid.quantity)
            dst.set_band_description(1, grid.product or DESCRIPTIONS[grid.quantity])
            dst.units = (grid.unit,)
    except RasterioError as exc:
        raise MapError(f"{path}: cannot write GeoTIFF: {exc}") from None
