"""`vrsim fit LOG [--scenario FILE] [--machine FILE] [--split FRACTION] [--validate LOG2] [--out DIR]
[--json]`: the twin of the machine that wrote an as-applied log (`services.sim.fit`): its dead time,
pass-start preset, steady offset and loop speed, written as ``machine_fit.toml`` for ``--machine``."""

from __future__ import annotations

import os

HELP = "fit the machine's response to its own as-applied log (the twin: machine_fit.toml)"
NOT_CONVERGED = 3   # exit code: the fit did not converge (its best figures are printed)


def configure(parser) -> None:
    from vrsim.services.cli.log_options import add_log_options

    add_log_options(parser)
    parser.add_argument("--split", type=float, default=None, metavar="FRACTION",
                        help="fit on the log's first FRACTION of time (0 to 1) and judge the twin on the "
                             "rest")
    parser.add_argument("--validate", metavar="LOG2",
                        help="also replay the fitted twin on another log of the same machine (never "
                             "fitted on)")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="write machine_fit.toml and fit.json into DIR (default: "
                             "runs/fit-<log>-<time>/)")
    parser.add_argument("--json", action="store_true", help="print the fit as one JSON object")


def run(args) -> int:
    from vrsim.common import ScenarioError
    from vrsim.services.cli.log_options import replay_input
    from vrsim.services.cli.run import default_out_dir
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.outputs.fit import fit_summary, fit_text, write_fit
    from vrsim.services.sim.fit import fit_machine
    from vrsim.services.sim.replay import replay_records
    from vrsim.services.sim.replay_setup import replay_scenario

    records, scenario, _ = replay_input(args, args.log)
    rows = None
    if args.split is not None:
        if not 0.0 < args.split < 1.0:
            raise ScenarioError(f"--split {args.split!r}: must be a fraction of the log's time between 0 "
                                "and 1")
        rows = records.time_s <= records.time_s[0] + args.split * (records.time_s[-1] - records.time_s[0])
    fit = fit_machine(records, scenario, rows)
    validated = None
    if args.validate:
        other, _, _ = replay_input(args, args.validate, select=False)   # the fitted machine, its sections
        validated = replay_records(other, replay_scenario(other, fit.scenario)).summary
    stem = os.path.splitext(os.path.basename(os.path.normpath(args.log)))[0]
    out = args.out or default_out_dir(stem, "fit")
    summary = fit_summary(fit, validated)
    write_fit(fit, summary, out, os.path.abspath(args.log))
    summary["out_dir"] = out
    print(dumps_text(summary, indent=True) if args.json else fit_text(fit, validated, out, records.unit))
    return 0 if fit.converged else NOT_CONVERGED
