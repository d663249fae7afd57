"""`vrsim calibrate SCENARIO [--revolutions N] [--scale-error-g G] [--json]`: the operator's meter
calibration, simulated, and the constant to put in the scenario."""

from __future__ import annotations

HELP = "simulate the meter's calibration test (turn, catch, weigh) and print the constant to configure"


def configure(parser) -> None:
    from services.sim.calibrate import DEFAULT_REVOLUTIONS, DEFAULT_SCALE_ERROR_G

    parser.add_argument("scenario", help="scenario TOML file or built-in name")
    parser.add_argument("--revolutions", type=int, default=DEFAULT_REVOLUTIONS, metavar="N",
                        help=f"shaft revolutions turned into the bucket (default {DEFAULT_REVOLUTIONS})")
    parser.add_argument("--scale-error-g", type=float, default=DEFAULT_SCALE_ERROR_G, metavar="G",
                        help="standard deviation of the scale's reading, g "
                             f"(default {DEFAULT_SCALE_ERROR_G:g})")
    parser.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                        help="override a scenario key, as for vrsim run (repeatable)")
    parser.add_argument("--json", action="store_true", help="print the outcome as one JSON object")


def run(args) -> int:
    from services.outputs.encode import dumps_text
    from services.sim import scenario
    from services.sim.calibrate import calibrate
    from services.sim.overrides import parse_assignment

    sc = scenario.load(args.scenario, [parse_assignment(text) for text in args.overrides])
    result = calibrate(sc, args.revolutions, args.scale_error_g)
    if args.json:
        print(dumps_text({**vars(result), "change_pct": result.change_pct, "settings": result.settings},
                         indent=True))
    else:
        print(result.text())
    return 0
