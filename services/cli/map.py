"""`vrsim map`: inspect, sample, convert and plot prescription maps."""

from __future__ import annotations

import argparse
import math
import os
import sys

from vrsim.common import MapError
from vrsim.services.cli.options import add_input_cap, apply_input_cap, warnings_as_lines
from vrsim.services.outputs.encode import dumps_text

HELP = "prescription maps: info, sample, convert, plot, boundary"


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

    p = sub.add_parser("info", help="what the file holds (layers, attributes and their values, the rate "
                                    "attribute and why, zones, area, CRS); with a unit, the rates")
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
    p.add_argument("--out", dest="out_option", metavar="OUT.png", help="output .png")
    p.add_argument("out", nargs="?", help=argparse.SUPPRESS)  # the older form: OUT.png as an argument

    p = sub.add_parser("boundary", help="write the field a zone prescription covers (its zones' union: "
                                        "holes kept, slivers dropped, invalid rings repaired) as GeoJSON")
    p.add_argument("file", help="zone map: shapefile (.shp/.zip/folder), GeoPackage, GeoJSON")
    p.add_argument("out", nargs="?", help="output .geojson (WGS84)")
    p.add_argument("--out", dest="out_option", metavar="OUT.geojson", help="output .geojson (the same)")
    p.add_argument("--layer", metavar="NAME", help="the shapefile of a zip or folder holding several")
    p.add_argument("--crs", help="CRS of a file that does not state one (a shapefile without .prj)")
    p.add_argument("--sliver-m2", type=float, default=None, metavar="M2",
                   help="drop parts and holes of the union smaller than this (m^2; default 100)")
    add_input_cap(p)


def _read(args):
    from vrsim import maps

    return maps.read_map(args.file, rate_field=args.rate_field, cell_size_m=args.cell_size, crs=args.crs,
                         max_cells=args.max_cells or None, layer=args.layer, product=args.product,
                         unit=args.unit, density_kg_l=args.density_kg_l)


def run(args) -> int:
    warnings_as_lines("map")
    if getattr(args, "max_cells", 0) < 0:
        raise MapError(f"--max-cells {args.max_cells}: must be >= 0")
    apply_input_cap(args)
    return {"info": _info, "sample": _sample, "convert": _convert, "plot": _plot,
            "boundary": _boundary}[args.map_command](args)


def _info(args) -> int:
    """What the file holds first (`maps.zone_table.describe_zones` for a zone file: no unit needed),
    then, when its unit is known (stated or ``--unit``), the rates in it (`maps.Grid.info`); another
    map whose unit is neither stated nor given shows its values as stored."""
    described, stand_in = _described(args), None
    if described is None:
        grid, stand_in = _grid_or_values(args)
    else:
        grid = _read(args) if args.unit is not None or described["stated_unit"] else None
    info = grid.info() if grid is not None else {}
    if stand_in:  # values as stored, in no unit; why
        info = ({k: v for k, v in info.items() if not k.endswith("_kg_ha")}
                | {"unit": None, "rate_unit": None, "unit_problem": stand_in})
    if described is not None and grid is not None and described["rate_attribute"]:
        info["rate_attribute_used"] = described["rate_attribute"]
    if args.json:
        print(dumps_text({**(described or {}), **info}))
        return 0
    if described is not None:
        _print_described(described, args.unit)
    if stand_in:
        print(f"{'unit':16} {stand_in}: the values below are as stored; give --unit (kg/ha, lb/ac, L/ha, "
              "gal/ac, seeds/ac, ...) to read them as rates")
    if "rate_attribute_used" in info:
        print(f"{'rates read from':16} attribute {info['rate_attribute_used']!r} in {grid.map_unit}")
    for key, value in info.items():
        if key in ("unit", "unit_problem", "rate_attribute_used") or key.endswith("_rate_kg_ha"):
            continue
        if key.endswith("_rate") and value is not None:
            value = f"{value:.6g} {info['rate_unit'] or ''}".rstrip()
        elif key == "rate_unit" and value is None:
            value = "not stated"
        elif isinstance(value, list):
            value = "[" + ", ".join(f"{v:.9g}" for v in value) + "]"
        elif isinstance(value, float):
            value = f"{value:.6g}"
        print(f"{key:16} {value}")
    return 0


def _described(args) -> dict | None:
    """`describe_zones` of a zone file (polygons with attributes), None for any other map."""
    from vrsim.maps.points import geojson_is_points
    from vrsim.maps.zone_table import describe_zones, is_zone_file, read_zone_table
    from vrsim.maps.zones import load_geojson

    path = args.file
    if not os.path.exists(path) or not is_zone_file(path):
        return None
    if path.lower().endswith((".geojson", ".json")) and geojson_is_points(load_geojson(path), path):
        return None
    return describe_zones(read_zone_table(path, layer=args.layer, crs=args.crs), args.rate_field)


def _grid_or_values(args):
    """(the map, None); or, for a map whose unit is neither stated nor readable and not given
    (`maps.units.MapUnitError`), (its values read with a stand-in unit, why its own unit does not do):
    what it holds, before its unit is known."""
    from vrsim.maps.units import MapUnitError

    try:
        return _read(args), None
    except MapUnitError as exc:
        if args.unit is not None:
            raise
        return _read(argparse.Namespace(**{**vars(args), "unit": "kg/ha"})), exc.problem


def _print_described(d: dict, unit: str | None) -> None:
    print(f"{'source':16} {d['source']}")
    if d["layer"]:
        print(f"{'layer':16} {d['layer']}")
    print(f"{'file_crs':16} {d['file_crs'] or 'not stated (no .prj): give --crs'}")
    area = f", {d['zones_area_ha']:,.2f} ha" if d["zones_area_ha"] is not None else ""
    print(f"{'zones':16} {d['zones']:,} polygons{area}")
    print(f"{'attributes':16} {len(d['attributes'])}")
    for name, a in d["attributes"].items():
        shown = (": " + ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in a["values"])
                 if "values" in a else f", {a['range'][0]:g} .. {a['range'][1]:g}" if "range" in a else "")
        print(f"  {name:14} {a['type']}, {a['count']:,} values, {a['distinct']:,} distinct{shown}")
    why = d["rate_attribute_why"]
    print(f"{'rate_attribute':16} {d['rate_attribute'] + ' (' + why + ')' if d['rate_attribute'] else why}")
    if d["stated_unit"]:
        print(f"{'unit':16} {d['stated_unit']} (stated: {d['stated_in']})")
    elif unit:
        print(f"{'unit':16} {unit} (given with --unit; the file states none)")
    else:
        print(f"{'unit':16} not stated in the file: give --unit (kg/ha, lb/ac, L/ha, gal/ac, seeds/ac, ...) "
              "to see the rates in it")


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
    from vrsim import maps

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

    from vrsim.common.written import write_failure, written

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


def _output(args, action: str, ext: str, older: bool = False) -> str:
    """OUT from ``--out`` or the positional form (`older`: the positional form is the older one, taken
    with a note on stderr), checked to end in `ext`."""
    if args.out and args.out_option:
        raise MapError(f"map {action}: give the output once, with --out")
    out = args.out_option or args.out
    if not out:
        raise MapError(f"map {action}: give the output with --out OUT{ext}")
    if args.out and older:
        print(f"vrsim map: note: `vrsim map {action} FILE OUT` is the older form; write `--out {out}`",
              file=sys.stderr)
    if not out.lower().endswith(ext):
        raise MapError(f"map {action}: output {out!r} must end in {ext}")
    return out


def _plot(args) -> int:
    from vrsim.common.written import written
    from vrsim.maps.plot import plot_map

    out = _output(args, "plot", ".png", older=True)
    grid = _read(args)
    with written(out, MapError) as temp:
        plot_map(grid.as_map_unit(), temp)
    print(f"wrote {out}")
    return 0


def _boundary(args) -> int:
    """`vrsim map boundary RX OUT.geojson`: the field `[field] from_map = true` takes, for a look in QGIS."""
    import json

    from vrsim.common import VehicleError
    from vrsim.common.written import written
    from vrsim.services.sim.world import field_from_map
    from vrsim.vehicle.field import SLIVER_M2

    out = _output(args, "boundary", ".geojson")
    try:
        field = field_from_map(args.file, crs=args.crs, layer=args.layer,
                               sliver_m2=SLIVER_M2 if args.sliver_m2 is None else args.sliver_m2)
    except VehicleError as exc:
        raise MapError(str(exc)) from None
    feature = field.to_geojson()
    with written(out, MapError) as temp, open(temp, "w") as fh:
        json.dump({"type": "FeatureCollection", "features": [feature]}, fh)
    props = feature["properties"]
    print(f"wrote {out} (one polygon of {props['area_ha']:,.2f} ha, {props['holes']} "
          f"hole{'s' * (props['holes'] != 1)}, WGS84; the field's UTM zone is {props['utm_crs']})")
    return 0
