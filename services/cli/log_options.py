"""The options of the commands that read a machine's as-applied log as a drive (`vrsim replay`,
`vrsim fit`): the log, how to read it, and the machine to run it with."""

from __future__ import annotations


def add_log_options(parser) -> None:
    parser.add_argument("log", help="the as-applied log: a John Deere point export (zipped shapefile), a "
                                    "GeoPackage, or a TASKDATA with TimeLogs")
    parser.add_argument("--scenario", metavar="FILE",
                        help="the machine and controller (a scenario file); default: made from the log "
                             "(a volume rate: a boom sprayer with flow control)")
    parser.add_argument("--machine", metavar="FILE",
                        help="a machine file (machine_fit.toml from vrsim fit) set over the scenario")
    parser.add_argument("--layer", metavar="NAME", help="the layer of a file holding several")
    parser.add_argument("--product", metavar="NAME|PDTn", help="the product of a TASKDATA holding several")
    parser.add_argument("--rate-field", metavar="NAME", help="attribute (or DDI) of the applied rate")
    parser.add_argument("--target-field", metavar="NAME", help="attribute (or DDI) of the target rate")
    parser.add_argument("--unit", help="unit of the log's rates when it does not say (gal/ac, L/ha, "
                                       "kg/ha, ...)")
    parser.add_argument("--crs", help="CRS of a shapefile without .prj")


def records_and_scenario(args, path: str):
    """The log at `path` as machine records (`maps.log_records`) and the scenario that replays it
    (`services.sim.replay_setup.replay_scenario`: ``--scenario`` or the log's, ``--machine`` over it)."""
    from dataclasses import replace

    import maps
    from maps.log_records import machine_records
    from services.sim.replay_setup import machine_overrides, replay_scenario
    from services.sim.scenario import load

    log = maps.read_point_log(path, rate_field=args.rate_field, target_field=args.target_field,
                              unit=args.unit, crs=args.crs, layer=args.layer, product=args.product)
    if args.unit and not log.unit:
        log = replace(log, unit=args.unit)
    records = machine_records(log)
    fragment = machine_overrides(args.machine) if args.machine else []
    scenario = load(args.scenario) if args.scenario else None
    return records, replay_scenario(records, scenario, fragment)
