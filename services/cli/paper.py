"""`vrsim paper`: the seed paper's experiment on vrsim's model, side by side with the paper's figures."""

from __future__ import annotations

import os

from vrsim.common import VrsimError

HELP = "reproduce Liang et al. 2013: ultimate gain and P/PI/PID step responses, paper vs vrsim"
DEFAULT_OUT = os.path.join("runs", "paper")


def configure(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    parser.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                        help=f"directory for step_responses.png (default: {DEFAULT_OUT})")


def run(args) -> int:
    from vrsim.controller.experiment import run_paper
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.outputs.paper import plot, table

    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise VrsimError(f"--out {args.out!r}: cannot create the directory ({exc.strerror})") from None
    result = run_paper()
    png = os.path.join(args.out, "step_responses.png")
    try:
        plot(result, png)
    except OSError as exc:
        raise VrsimError(f"--out {args.out!r}: cannot write {png} ({exc.strerror})") from None
    if args.json:
        print(dumps_text(result.summary))
    else:
        print(table(result.summary))
        print(f"\nwrote {png}")
    return 0
