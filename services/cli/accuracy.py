"""`vrsim accuracy [--update --reason TEXT] [--json]`: run the accuracy regression library."""

from __future__ import annotations

import sys

HELP = "run the accuracy regression library and compare it with the recorded figures"


def configure(parser) -> None:
    parser.add_argument("--update", action="store_true",
                        help="rewrite tests/accuracy/expected.json with the measured figures")
    parser.add_argument("--reason", default="", help="why the figures change (required with --update)")
    parser.add_argument("--json", action="store_true", help="print the comparison as JSON")
    parser.add_argument("--scenario", action="append", default=None,
                        help="run only this library scenario (repeatable)")
    parser.add_argument("--workers", type=int, default=None, help="parallel runs (default: cores)")


def run(args) -> int:
    from vrsim.common import ScenarioError
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.sim import accuracy

    if args.update and not args.reason.strip():
        raise ScenarioError("--update needs --reason TEXT saying why the figures change")
    known = accuracy.scenario_names()
    for name in args.scenario or []:
        if name not in known:
            raise ScenarioError(f"--scenario {name!r}: not in the library ({', '.join(known)})")
    results = accuracy.run_library(args.scenario, args.workers)
    if args.update:
        accuracy.update(results, args.reason)
        print(f"updated {accuracy.EXPECTED} ({len(results)} scenarios); reason logged in "
              f"{accuracy.CHANGELOG}")
        return 0
    expected = accuracy.load_expected()
    checks = [c for name, summary in results.items() for c in accuracy.compare(name, summary, expected)]
    moved = [c for c in checks if c.moved]
    if args.json:
        print(dumps_text({"scenarios": sorted(results), "moved": len(moved), "checks": checks}, indent=True))
    else:
        print(accuracy.table(checks))
        print(f"\n{len(results)} scenarios, {len(checks)} figures, {len(moved)} moved beyond tolerance")
    if moved:
        print("accuracy: figures moved beyond tolerance:\n" + accuracy.table(moved), file=sys.stderr)
        return 1
    return 0
