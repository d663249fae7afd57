"""`vrsim controller analyze [SCENARIO] [--json] [--out DIR]`: the scenario's controller on its plant:
loop margins, crossover and bandwidth, response time and look-ahead; bode.png and step.png."""

from __future__ import annotations

HELP = "analyse a scenario's controller: margins, crossover, bandwidth, response time; bode.png, step.png"
ACTIONS = ("analyze",)


def configure(parser) -> None:
    parser.add_argument("action", choices=ACTIONS, metavar="ACTION", help="analyze")
    parser.add_argument("scenario", nargs="?", default=None,
                        help="scenario TOML file or built-in name (default: the built-in 'default')")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="folder for bode.png and step.png (default: runs/analyze-<scenario>-<time>/)")


def run(args) -> int:
    from vrsim.services.cli.run import default_out_dir
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.outputs.loop_analysis import text, write_pictures
    from vrsim.services.sim import scenario
    from vrsim.services.sim.analyze import analyze_controller

    sc = scenario.load(args.scenario)
    report = analyze_controller(sc)
    out_dir = args.out or default_out_dir(sc.name, "analyze")
    paths = write_pictures(report, out_dir)
    if args.json:
        print(dumps_text({**report.to_dict(), "files": paths}, indent=True))
    else:
        print(text(report))
        print(f"  wrote {', '.join(paths)}")
    return 0
