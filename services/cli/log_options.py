"""The options of the commands that read a machine's as-applied log as a drive (`vrsim replay`,
`vrsim fit`): the log, how to read it, which of its records, and the machine to run it with
(`replay_input`)."""

from __future__ import annotations


def add_log_reading(parser) -> None:
    """The log and how to read it: what `vrsim evaluate`, `replay` and `fit` share."""
    parser.add_argument("log", help="the log: a point shapefile (.shp or zipped, e.g. a John Deere "
                                    "export), a GeoPackage, or a TASKDATA (folder, TASKDATA.XML or .zip) "
                                    "with TimeLogs")
    parser.add_argument("--layer", metavar="NAME",
                        help="the layer of a zip, folder or GeoPackage holding several (listed when none "
                             "is named)")
    parser.add_argument("--product", metavar="NAME|PDTn",
                        help="the product of a TASKDATA (the log's, logging the rates of several on their "
                             "device elements, or the prescription's) holding several (listed when none is "
                             "named)")
    parser.add_argument("--rate-field", metavar="NAME",
                        help="attribute (or TimeLog DDI, e.g. 7 or 0x0007) of the applied rate "
                             "(default: found by name: AppliedRate, applied, ...; DDI 7, else 2)")
    parser.add_argument("--target-field", metavar="NAME",
                        help="attribute (or DDI) of the target rate (default: TargetRate, target, ...; "
                             "DDI 6, else 1)")
    parser.add_argument("--unit", help="unit of the log's rates when it does not say (kg/ha, t/ha, lb/ac, "
                                       "L/ha, gal/ac, floz/ac, ...)")
    parser.add_argument("--crs", help="CRS of a shapefile without .prj")


def add_log_options(parser) -> None:
    """`add_log_reading`, the machine that replays the log, its target and which of its records."""
    add_log_reading(parser)
    parser.add_argument("--scenario", metavar="FILE",
                        help="the machine: a scenario TOML file or built-in name, given the log's sections "
                             "(default: made from the log: a boom sprayer for a volume rate, else the "
                             "built-in default's meter)")
    parser.add_argument("--machine", metavar="FILE",
                        help="a machine fragment (TOML tables of scenario keys, e.g. machine_fit.toml) set "
                             "on the scenario")
    parser.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                        help="override a key of the machine, after --machine (controller.kp=0.8; repeatable)")
    parser.add_argument("--prescription", metavar="MAP",
                        help="take each record's target from this map at its position (any map vrsim "
                             "reads) instead of the logged target")
    parser.add_argument("--session", metavar="N", type=int, nargs="+", action="extend",
                        help="only these sessions (from 0; records more than 60 s apart begin a new "
                             "session; default: all)")
    parser.add_argument("--start-s", type=float, metavar="S",
                        help="only records from S seconds after the log's first record")
    parser.add_argument("--end-s", type=float, metavar="S",
                        help="only records up to S seconds after the log's first record")


def replay_input(args, path: str, select: bool = True):
    """(records, scenario, extras) of the log at `path`: its records (`maps.log_records`; with `select`,
    those of ``--session`` between ``--start-s`` and ``--end-s``), the scenario that replays them
    (`services.sim.replay_setup.replay_scenario`: ``--scenario`` or the log's, ``--machine`` over it),
    and what the summary should say of the choices (``log_sessions``, ``target_from``, ...)."""
    from vrsim.maps.log_records import machine_records

    log = read_log(path, args.rate_field, args.target_field, args.unit, args.crs, args.layer, args.product,
                   target_optional=bool(getattr(args, "prescription", None)))
    chosen = (args.session, args.start_s, args.end_s) if select else (None, None, None)
    records, sessions = _selected(machine_records(log), *chosen)
    records, scenario, extra = _machine_and_target(records, args)
    return records, scenario, {"log": records.source, "log_sessions": sessions, **extra}


def read_log(path: str, rate_field=None, target_field=None, unit=None, crs=None, layer=None, product=None,
             target_optional=False):
    """The as-applied log at `path` (`maps.pointlog.read_point_log`) with its rates' unit checked."""
    from vrsim.maps.pointlog import read_point_log

    log = read_point_log(path, rate_field=rate_field, target_field=target_field, unit=unit, crs=crs,
                         layer=layer, product=product, target_optional=target_optional)
    return _with_unit(log, unit)


def _with_unit(log, unit: str | None):
    """`log` with its rates' unit checked (and ``--unit`` where the log does not say one)."""
    from dataclasses import replace

    from vrsim.common import MapError
    from vrsim.maps.units import is_rate_unit, rate_unit

    if unit and not log.unit:   # a TimeLog of a DDI vrsim knows no unit of
        log = replace(log, unit=unit)
    if not is_rate_unit(log.unit):
        raise MapError(f"{log.source}: the unit of its rates is {log.unit or 'not stated'!r}; give it with "
                       "--unit (kg/ha, lb/ac, L/ha, gal/ac, ...)")
    return replace(log, unit=rate_unit(log.unit))


def _selected(records, sessions, start_s, end_s):
    """(records, the log's session numbers kept): the records of `sessions` (all: None) between
    `start_s` and `end_s` (seconds since the log's first record), their sessions renumbered from 0."""
    from dataclasses import replace

    import numpy as np

    from vrsim.common import MapError

    keep = np.ones(records.rows, dtype=bool)
    if sessions:
        bad = [s for s in sessions if not 0 <= s < records.sessions]
        if bad:
            raise MapError(f"--session {bad[0]}: {records.source} has {records.sessions} session(s), "
                           f"numbered 0 to {records.sessions - 1}")
        keep &= np.isin(records.session, sessions)
    keep &= _window(records, start_s, end_s)
    if not keep.any():
        given = " ".join(f"{name} {value:g}" for name, value in (("--start-s", start_s), ("--end-s", end_s))
                         if value is not None)
        raise MapError(f"{given}: no record of {records.source} in that window "
                       f"(its records run from {records.time_s[0]:.1f} to {records.time_s[-1]:.1f} s"
                       f"{' in the sessions chosen' if sessions else ''})")
    part = records.take(keep)
    chosen, session = np.unique(part.session, return_inverse=True)
    return replace(part, session=session.astype(records.session.dtype)), [int(s) for s in chosen]


def _window(records, start_s, end_s):
    """The records from `start_s` to `end_s` (None: no bound), both checked."""
    import math

    from vrsim.common import MapError

    for name, value in (("--start-s", start_s), ("--end-s", end_s)):
        if value is not None and not math.isfinite(value):
            raise MapError(f"{name} {value}: must be a number of seconds since the log's first record")
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise MapError(f"--end-s {end_s:g}: must be after --start-s {start_s:g}")
    lo = -math.inf if start_s is None else start_s
    hi = math.inf if end_s is None else end_s
    return (records.time_s >= lo) & (records.time_s <= hi)


def _machine_and_target(records, args):
    """(records, scenario, summary extras): the scenario a replay runs (`replay_scenario`), and with
    ``--prescription`` the records' target taken from the map; a log without a target exits 2."""
    from dataclasses import replace

    import numpy as np

    from vrsim.common import MapError
    from vrsim.services.sim.replay_setup import replay_scenario
    from vrsim.services.sim.scenario import load

    user = load(args.scenario) if args.scenario else None
    from vrsim.services.cli.options import overrides_of

    fragment = overrides_of(args)
    scenario = replay_scenario(records, user, fragment)
    extra = {"target_from": "log"}
    if args.prescription:
        target, off = _prescribed(records, args.prescription, args.product, scenario.product.density_kg_l)
        records = replace(records, target=target)
        scenario = replay_scenario(records, user, fragment)   # a machine from the log suits these rates
        extra = {"target_from": args.prescription, "off_prescription_records": off}
    elif not np.isfinite(records.target).any():
        field = (f"--target-field {args.target_field}" if args.target_field
                 else "found by name: TargetRate, target, ...; DDI 6, else 1")
        raise MapError(f"{records.source}: its target rate ({field}) holds no value: a replay needs each "
                       "record's target; give a prescription with --prescription MAP")
    return records, scenario, extra


def _prescribed(records, path: str, product: str | None, density_kg_l: float | None):
    """(target, off): the prescription at each record's position in the log's unit (0 where a record
    lies off the map or on a nodata cell: no rate given there), and how many records that is."""
    import numpy as np

    from vrsim import maps
    from vrsim.common import MapError
    from vrsim.maps.units import convert_rate

    grid = maps.read_map(path, product=product, density_kg_l=density_kg_l)
    found = grid.lookup(records.x_m, records.y_m, crs=records.crs)   # reprojected to the map's CRS
    on_map = np.isfinite(found.rate_kg_ha)
    if not on_map.any():
        raise MapError(f"--prescription {path}: no record of {records.source} lies on the map's rates "
                       "(another field, or another CRS)")
    try:
        target = convert_rate(found.rate_kg_ha, grid.unit, records.unit, density_kg_l)
    except MapError as exc:
        raise MapError(f"--prescription {path} ({grid.map_unit}) against the log's {records.unit}: {exc}; "
                       "give [product] density_kg_l in --scenario or --machine") from None
    return np.where(on_map, target, 0.0), int((~on_map).sum())
