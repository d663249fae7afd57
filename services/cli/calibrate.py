"""`vrsim calibrate SCENARIO [--revolutions N] [--scale-error-g G] [--seconds S] [--jug-error-ml ML]
[--set KEY=VALUE ...] [--json]`: the operator's meter calibration, simulated (a granular meter turned
and weighed; a sprayer's flow meter by a catch test), and the constant to put in the scenario."""

from __future__ import annotations

HELP = ("simulate the meter's calibration test (turn and weigh; a sprayer's catch test) and print the "
        "constant to configure")


def configure(parser) -> None:
    from vrsim.services.cli.options import add_overrides
    from vrsim.services.sim.calibrate import (
        DEFAULT_CATCH_S,
        DEFAULT_JUG_ERROR_ML,
        DEFAULT_REVOLUTIONS,
        DEFAULT_SCALE_ERROR_G,
    )

    parser.add_argument("scenario", help="scenario TOML file or built-in name")
    parser.add_argument("--revolutions", type=int, default=DEFAULT_REVOLUTIONS, metavar="N",
                        help=f"shaft revolutions turned into the bucket (default {DEFAULT_REVOLUTIONS})")
    parser.add_argument("--scale-error-g", type=float, default=DEFAULT_SCALE_ERROR_G, metavar="G",
                        help="standard deviation of the scale's reading, g "
                             f"(default {DEFAULT_SCALE_ERROR_G:g})")
    parser.add_argument("--seconds", type=float, default=DEFAULT_CATCH_S, metavar="S",
                        help=f"sprayer: seconds the boom sprays into the catch (default {DEFAULT_CATCH_S:g})")
    parser.add_argument("--jug-error-ml", type=float, default=DEFAULT_JUG_ERROR_ML, metavar="ML",
                        help="sprayer: standard deviation of the jug's reading, mL "
                             f"(default {DEFAULT_JUG_ERROR_ML:g})")
    add_overrides(parser)
    parser.add_argument("--json", action="store_true", help="print the outcome as one JSON object")


def run(args) -> int:
    from vrsim.services.cli.options import load_scenario
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.sim.calibrate import calibrate
    from vrsim.services.sim.display import figures_display, scenario_units

    sc = load_scenario(args)
    result = calibrate(sc, args.revolutions, args.scale_error_g, args.seconds, args.jug_error_ml)
    units = scenario_units(sc)  # [output] units, or the map's
    if args.json:
        print(dumps_text({**vars(result), "change_pct": result.change_pct, "settings": result.settings,
                          "units": units, "display": figures_display(vars(result), units)}, indent=True))
    else:
        print(result.text(units))
    return 0
