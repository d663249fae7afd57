"""`vrsim evaluate LOG [--prescription RX] [--product NAME|PDTn] [--rate-field NAME] [--target-field NAME]
[--layer NAME] [--field BOUNDARY] [--delay-s S] [--include-zero-target] [--standstill-m-s M_S]
[--outlier-multiple X] [--include-outliers] [--unit UNIT] [--prescription-unit UNIT] [--density-kg-l KG_L]
[--crs CRS] [--json] [--out DIR]`: the accuracy of a machine's as-applied log (`services.sim.evaluate`)."""

from __future__ import annotations

HELP = "accuracy of an as-applied log (TASKDATA TimeLogs, point shapefile or GeoPackage)"


def configure(parser) -> None:
    from vrsim.services.cli.log_options import add_log_reading
    from vrsim.services.sim.metrics import OUTLIER_MULTIPLE, STANDSTILL_M_S

    add_log_reading(parser)
    parser.add_argument("--prescription", metavar="RX",
                        help="compare with this map at each point (any map vrsim reads) instead of the "
                             "logged target")
    parser.add_argument("--field", metavar="BOUNDARY",
                        help="field boundary (GeoJSON, shapefile, KML/KMZ or an ISOXML TASKDATA's partfield; "
                             "holes kept): only points inside it are compared")
    parser.add_argument("--delay-s", type=float, default=0.0, metavar="S",
                        help="delivery delay: product metered at a record's time lands S s later, where the "
                             "machine is then; compared with the prescription there (default 0)")
    parser.add_argument("--include-zero-target", action="store_true",
                        help="also compare records whose target is 0 (left out by default: the machine was "
                             "told not to apply there)")
    parser.add_argument("--standstill-m-s", type=float, default=STANDSTILL_M_S, metavar="M_S",
                        help="records at a ground speed below this (m/s) are left out and counted: a "
                             "machine barely moving logs its flow over almost no ground (default "
                             f"{STANDSTILL_M_S:g}; 0: none)")
    parser.add_argument("--outlier-multiple", type=float, default=OUTLIER_MULTIPLE, metavar="X",
                        help="records applying more than X times their target are outliers: counted and "
                             f"left out (default {OUTLIER_MULTIPLE:g})")
    parser.add_argument("--include-outliers", action="store_true",
                        help="keep the outliers in the figures (they are still counted)")
    parser.add_argument("--prescription-unit", metavar="UNIT",
                        help="unit of the prescription's rates when the map does not say")
    parser.add_argument("--density-kg-l", type=float, metavar="KG_L",
                        help="the product's density (kg/L): compares a volume rate log (gal/ac) with a mass "
                             "rate map (kg/ha), or the other way round")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    parser.add_argument("--out", metavar="DIR",
                        help="also write evaluation.json, error.tif, error_map.png, timeseries.png and "
                             "report.html into DIR")


def run(args) -> int:
    from dataclasses import replace

    from vrsim import maps
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.outputs.evaluation import text_evaluation, write_evaluation
    from vrsim.services.sim.evaluate import error_grid, evaluate

    log = maps.read_point_log(args.log, rate_field=args.rate_field, target_field=args.target_field,
                              unit=args.unit, crs=args.crs, layer=args.layer, product=args.product)
    if args.unit and not log.unit:  # a TimeLog of a DDI vrsim knows no unit of
        log = replace(log, unit=args.unit)
    rx = maps.read_map(args.prescription, product=args.product, unit=args.prescription_unit,
                       density_kg_l=args.density_kg_l) if args.prescription else None
    field = _field(args.field) if args.field else None
    ev = evaluate(log, rx, field=field, delay_s=args.delay_s,
                  include_zero_target=args.include_zero_target, density_kg_l=args.density_kg_l,
                  standstill_m_s=args.standstill_m_s, outlier_multiple=args.outlier_multiple,
                  include_outliers=args.include_outliers)
    if args.out:
        write_evaluation(ev, error_grid(ev, rx), args.out)
    print(dumps_text(ev.summary(), indent=True) if args.json else text_evaluation(ev))
    if args.out and not args.json:
        print(f"  outputs in {args.out}/ (report.html, error_map.png, timeseries.png, error.tif, "
              f"evaluation.json)")
    return 0


def _field(path: str):
    from vrsim.common import MapError, VehicleError
    from vrsim.vehicle import Field

    try:
        return Field.from_file(path)
    except VehicleError as exc:
        raise MapError(f"--field {exc}") from None
