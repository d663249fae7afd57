"""`vrsim tune SCENARIO [--controller KIND|FILE] --param NAME=LOW:HIGH ... --objective METRIC [--budget N]
[--seed S] [--out DIR] [--json]`: search a controller's parameters for the best figure on a field."""

from __future__ import annotations

import sys

HELP = "search a controller's parameters for the best figure on a field (differential evolution, batched)"


def configure(parser) -> None:
    parser.add_argument("scenario", nargs="?", default=None,
                        help="scenario TOML file or built-in name (default, large); with --log, the machine "
                             "(default: the log's)")
    parser.add_argument("--log", metavar="LOG",
                        help="judge candidates on this as-applied log's drive, replayed with the machine "
                             "(--machine machine_fit.toml: your machine's twin); objective "
                             "twin_mae_vs_target")
    parser.add_argument("--controller", metavar="KIND|FILE", default=None,
                        help="the controller to tune: a kind with its defaults (P, PI, PID, aog_pi, ff_pi, "
                             "smith, fuzzy_pid, ...) or a TOML file with a [controller] table (any kind, "
                             "python included); default: the scenario's own controller")
    parser.add_argument("--param", metavar="NAME=LOW:HIGH", action="append", required=True,
                        help="a parameter and its range (kp, ki, kd for P/PI/PID; the kind's params "
                             "otherwise, a python class's too; look_ahead_s for any); repeat for each")
    parser.add_argument("--objective", metavar="METRIC", required=True,
                        help="the figure to optimise, minimised, maximised or brought to zero by its "
                             "sense (mae_kg_ha, within_10pct_area_pct, bias_kg_ha, ...)")
    parser.add_argument("--budget", type=int, default=200, metavar="N",
                        help="about how many candidates to evaluate (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the search (default 0)")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="folder for best_controller.toml and history.csv "
                             "(default: runs/tune-<scenario>-<time>/)")
    parser.add_argument("--json", action="store_true", help="print the outcome as one JSON object")
    from vrsim.services.cli.options import add_overrides

    add_overrides(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress line on stderr")


def run(args) -> int:
    from vrsim.common import ScenarioError
    from vrsim.services.cli.options import load_scenario
    from vrsim.services.cli.run import default_out_dir
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.outputs.tune import tune_text, write_tune
    from vrsim.services.sim.tune import check_objective, parse_param, tune

    params = [parse_param(p) for p in args.param]
    check_objective(args.objective, args.log is not None)
    records = None
    if args.log:
        records, sc = _log_and_machine(args)
    elif args.scenario is None:
        raise ScenarioError("vrsim tune: give a SCENARIO, or --log LOG to tune on a machine's own log")
    else:
        sc = load_scenario(args)

    def progress(done, best):
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write(f"\rvrsim tune: {done} evaluations, best {args.objective} {best}   ")
            sys.stderr.flush()

    result = tune(sc, args.controller, params, args.objective, args.budget, args.seed, progress, log=records)
    if not args.quiet and sys.stderr.isatty():
        sys.stderr.write("\n")
    paths = write_tune(result, args.out or default_out_dir(sc.name, "tune"))
    if args.json:
        pairs = (("tuned_loop", result.tuned_loop), ("baseline_loop", result.baseline_loop))
        loops = {key: None if loop is None else loop.to_dict() for key, loop in pairs}
        print(dumps_text({"scenario": result.scenario, "objective": result.objective, "sense": result.sense,
                          "controller": result.best.kind, "best": result.best_values,
                          "best_objective": result.best_objective, "evaluations": result.evaluations,
                          "generations": result.generations, "tuned": result.tuned,
                          "baseline": result.baseline, **loops, "margin_warning": result.margin_warning,
                          **paths}, indent=True))
        if result.margin_warning:   # not only inside the JSON: a script's log shows it too
            print(f"vrsim tune: warning: the tuned loop's {result.margin_warning}", file=sys.stderr)
    else:
        print(tune_text(result))
        print(f"  files: {paths['best_controller']}, {paths['history']}")
    return 0


def _log_and_machine(args):
    """(records, scenario): the log of ``--log`` and the machine that replays it (SCENARIO or the log's,
    then ``--machine`` and ``--set``)."""
    from vrsim.maps.log_records import machine_records
    from vrsim.services.cli.log_options import read_log
    from vrsim.services.cli.options import overrides_of
    from vrsim.services.sim.replay_setup import replay_scenario
    from vrsim.services.sim.scenario import load

    records = machine_records(read_log(args.log))
    user = load(args.scenario) if args.scenario else None
    return records, replay_scenario(records, user, overrides_of(args))
