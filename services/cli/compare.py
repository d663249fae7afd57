"""`vrsim compare [SCENARIO] [--controller SPEC ...] [--look-ahead S|auto] [--json] [--out DIR]`: one
scenario, several controllers, one shared drive (same seed, SUMO track and sensor noise)."""

from __future__ import annotations

HELP = "run one scenario with several controllers on the same drive and compare their accuracy"


def configure(parser) -> None:
    parser.add_argument("scenario", nargs="?", default=None,
                        help="scenario TOML file or built-in name (default: the built-in 'default')")
    parser.add_argument("--controller", metavar="SPEC", action="append", default=None,
                        help="a built-in kind with its defaults (pid, aog_pi, ff_pi, smith, fuzzy_pid, "
                             "ideal; also P, PI, PID) or a TOML file with a [controller] table; repeat for "
                             "each (default: every built-in kind)")
    parser.add_argument("--look-ahead", metavar="S|auto", default=None,
                        help="look_ahead_s for every controller: seconds or auto (default: the scenario's, "
                             "unless a spec file sets its own)")
    parser.add_argument("--json", action="store_true",
                        help='print {"scenario": ..., "runs": [{"controller": SPEC, <vrsim run --json '
                             'keys>}, ...]}')
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="folder for compare.html and its pictures "
                             "(default: runs/compare-<scenario>-<time>/)")
    from vrsim.services.cli.options import add_overrides

    add_overrides(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar on stderr")


def _look_ahead_arg(text: str | None):
    """``--look-ahead``: None, "auto" or seconds (the scenario's rules check the range)."""
    from vrsim.common import ScenarioError
    from vrsim.controller.config import LOOK_AHEAD_AUTO

    if text is None or text == LOOK_AHEAD_AUTO:
        return text
    try:
        return float(text)
    except ValueError:
        raise ScenarioError(f"--look-ahead {text!r}: must be seconds or {LOOK_AHEAD_AUTO}") from None


def run(args) -> int:
    from vrsim.services.cli.options import load_scenario
    from vrsim.services.cli.run import Progress, default_out_dir
    from vrsim.services.outputs.compare import table_text, write_page
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.sim.compare import compare

    sc = load_scenario(args)
    bars = {}

    def progress(label, done, total):
        bar = bars.setdefault(label, Progress(f"vrsim compare {sc.name} {label}", enabled=not args.quiet))
        bar(done, total)
        if done >= total:
            bar.close()

    result = compare(sc, args.controller, _look_ahead_arg(args.look_ahead), progress)
    out_dir = args.out or default_out_dir(sc.name, "compare")
    page = write_page(result, out_dir)
    if args.json:
        print(dumps_text(result.to_dict(), indent=True))
    else:
        print(table_text(result))
        print(f"  page: {page}")
    return 0
