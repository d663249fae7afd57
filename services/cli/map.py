"""`vrsim map`: inspect, sample, convert and plot prescription maps."""

from __future__ import annotations

import argparse
import math
import sys

from common import MapError
from services.cli.options import add_input_cap, apply_input_cap
from services.outputs.encode import dumps_text

HELP = "prescription maps: info, sample, convert, plot"


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="map_command", metavar="ACTION", required=True)

    def reading(p):
        p.add_argument("file", help="map file: GeoTIFF, ISOXML TASKDATA (folder, TASKDATA.XML, .zip), "
                                    "shapefile (.shp/.zip), GeoJSON, CSV")
        p.add_argument("--rate-field", help="attribute holding the rate in zone/point files")
        p.add_argument("--unit", help="unit of the rates when the file does not state it (kg/ha, lb/ac, "
                                      "L/ha, gal/ac, seeds/ac, ...)")
        p.add_argument("--density-kg-l", type=float, metavar="KG_L",
                       help="the product's density (kg/L): a volume rate map also in kg/ha")
        p.add_argument("--layer", metavar="NAME",
                       help="the shapefile of a zip or folder holding several (listed when none is named)")
        p.add_argument("--product", metavar="NAME|PDTn",
                       help="the product of a TASKDATA grid holding several (listed when none is named)")
        p.add_argument("--cell-size", type=float, metavar="M", help="cell size for zone files, m")
        p.add_argument("--crs", help="CRS of a file that does not state one (e.g. a shapefile without .prj)")
        p.add_argument("--max-cells", type=int, default=200_000_000, metavar="N",
                       help="refuse grids with more cells (default 200,000,000; 0: no cap)")
        add_input_cap(p)

    p = sub.add_parser("info", help="format, CRS, bounds, cell size, size, rate statistics")
    reading(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")

    p = sub.add_parser("sample", help="the rate at a point (exit 0 inside or outside)")
    reading(p)
    p.add_argument("--lat", type=float, help="latitude, WGS84 degrees")
    p.add_argument("--lon", type=float, help="longitude, WGS84 degrees")
    p.add_argument("--x", type=float, help="x in the map's CRS")
    p.add_argument("--y", type=float, help="y in the map's CRS")
    p.add_argument("--json", action="store_true",
                   help='print {"rate_kg_ha", "rate", "rate_unit", "inside", "row", "col"}')

    p = sub.add_parser("convert", help="write the map in another format (by OUT's extension)")
    reading(p)
    p.add_argument("out", help="output: .tif; a folder, .../TASKDATA.XML or .zip (ISOXML grid type 2, never "
                               "overwriting); .shp.zip or .shp (shapefile zones, a rate attribute named "
                               "with its unit, e.g. Rate_kg_ha); .geojson (WGS84); .csv")
    p.add_argument("--to-crs", help="reproject first (nearest neighbour), e.g. EPSG:32632")
    p.add_argument("--to-cell-size", type=float, metavar="M", help="cell size when reprojecting, m")

    p = sub.add_parser("plot", help="draw the map to a PNG")
    reading(p)
    p.add_argument("out", help="output .png")


def _read(args):
    import maps

    return maps.read_map(args.file, rate_field=args.rate_field, cell_size_m=args.cell_size, crs=args.crs,
                         max_cells=args.max_cells or None, layer=args.layer, product=args.product,
                         unit=args.unit, density_kg_l=args.density_kg_l)


def _warnings_as_lines() -> None:
    """Map warnings (a repaired file) as one stderr line each, not Python's two-line format."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"vrsim map: warning: {message}", file=sys.stderr)

    warnings.showwarning = show


def run(args) -> int:
    _warnings_as_lines()
    if args.max_cells < 0:
        raise MapError(f"--max-cells {args.max_cells}: must be >= 0")
    apply_input_cap(args)
    return {"info": _info, "sample": _sample, "convert": _convert, "plot": _plot}[args.map_command](args)


def _info(args) -> int:
    info = _read(args).info()
    if args.json:
        print(dumps_text(info))
        return 0
    for key, value in info.items():
        if key == "unit" or key.endswith("_rate_kg_ha"):  # the text shows rates in the map's own unit
            continue
        if key.endswith("_rate") and value is not None:
            value = f"{value:.6g} {info['rate_unit']}"
        elif isinstance(value, list):
            value = "[" + ", ".join(f"{v:.9g}" for v in value) + "]"
        elif isinstance(value, float):
            value = f"{value:.6g}"
        print(f"{key:16} {value}")
    return 0


def _sample(args) -> int:
    geo = args.lat is not None or args.lon is not None
    proj = args.x is not None or args.y is not None
    if geo == proj:
        raise MapError("map sample: give --lat and --lon, or --x and --y")
    for name in ("lat", "lon") if geo else ("x", "y"):
        value = getattr(args, name)
        if value is None or not math.isfinite(value):
            raise MapError(f"map sample: --{name} {value}: a finite number is required")
    grid = _read(args)
    found = grid.sample(lat=args.lat, lon=args.lon) if geo else grid.sample(x=args.x, y=args.y)
    value = found["rate_kg_ha"]
    rate = None if value is None else float(grid.in_map_unit(value))
    res = {"rate_kg_ha": value if grid.unit == "kg/ha" else None, "rate": rate, "rate_unit": grid.map_unit,
           **{k: found[k] for k in ("inside", "row", "col")}}
    if args.json:
        print(dumps_text(res))
    elif not res["inside"]:
        print("outside the map")
    elif rate is None:
        print(f"nodata (row {res['row']}, col {res['col']})")
    else:
        print(f"{rate:.6g} {grid.map_unit} (row {res['row']}, col {res['col']})")
    return 0


def _convert(args) -> int:
    import maps

    if args.to_cell_size is not None and not args.to_crs:  # before reading: a big map takes a while
        raise MapError("map convert: --to-cell-size needs --to-crs")
    grid = _read(args)
    if args.to_crs:
        grid = grid.reproject(args.to_crs, cell_size_m=args.to_cell_size)
    _write_whole(lambda path: maps.write_map(grid, path, like=args.out), args.out)
    print(f"wrote {args.out} ({grid.rows} x {grid.cols} cells)")
    return 0


def _write_whole(write, out: str) -> None:
    """``write(path)`` for `out`, whole or not at all: a file or a new folder under a temporary name
    (`common.written.written`); an ISOXML export into a folder that exists (beside other exports) in
    place, what it added removed again if it fails."""
    import os

    from common.written import write_failure, written

    folder = os.path.dirname(out) or "." if out.lower().endswith(".xml") else out
    if not os.path.isdir(folder):
        with written(out, MapError) as temp:
            write(temp)
        return
    before = set(os.listdir(folder))
    try:
        write(out)
    except Exception as exc:
        failure = write_failure(exc, os.path.abspath(folder), MapError)
        for name in set(os.listdir(folder)) - before:
            os.remove(os.path.join(folder, name))
        if failure is not None:
            raise failure from None
        raise


def _plot(args) -> int:
    from maps.plot import plot_map

    if not args.out.lower().endswith(".png"):
        raise MapError(f"map plot: output {args.out!r} must end in .png")
    from common.written import written

    grid = _read(args)
    with written(args.out, MapError) as temp:
        plot_map(grid.as_map_unit(), temp)
    print(f"wrote {args.out}")
    return 0
