"""`vrsim machine pattern SCENARIO [--set KEY=VALUE ...] [--out DIR] [--json] [--tray-width M]`: a
spinner's simulated catch-tray test (EN 13739 / ISO 5690): CV across the driving width, the effective
working width at CV 15 %, and pattern.png, the transverse profile of three adjacent passes. The scenario
(with its ``--set`` keys, as for ``vrsim run``) is loaded and checked whole; a machine of another kind
is refused in one line (its strips side by side lay a flat rate, no spread pattern: ``vrsim run``
reports its ``cv_pct`` as null, not applicable)."""

from __future__ import annotations

from vrsim.services.cli.options import add_overrides

HELP = "a spinner's spread pattern: catch-tray CV, effective working width, pattern.png"
ACTIONS = ("pattern",)
PICTURE = "pattern.png"


def configure(parser) -> None:
    parser.add_argument("action", choices=ACTIONS, metavar="ACTION", help="pattern")
    parser.add_argument("scenario", help="scenario TOML file or built-in name whose [implement] is a spinner")
    add_overrides(parser, "override a scenario key, as for vrsim run (implement.spread_width_m=30); "
                          "repeatable")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help=f"folder for {PICTURE} (default: runs/pattern-<scenario>-<time>/)")
    parser.add_argument("--tray-width", type=float, default=0.5, metavar="M",
                        help="width of each catch tray across the passes, m (default 0.5)")


def run(args) -> int:
    import os

    from vrsim.services.cli.run import default_out_dir
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.sim.spread_pattern import CV_LIMIT_PCT, catch_tray_test

    name, spec, pattern, width_m = _spinner(args)
    test = catch_tray_test(spec, pattern, width_m, args.tray_width)
    out_dir = args.out or default_out_dir(name, "pattern")
    png = os.path.join(out_dir, PICTURE)
    _write_picture(test, spec, png)
    figures = {"cv_pct": round(test.cv_pct, 2), "cv_racetrack_pct": round(test.cv_racetrack_pct, 2),
               "effective_width_m": round(test.effective_width_m, 2), "cv_limit_pct": CV_LIMIT_PCT}
    if args.json:
        print(dumps_text({"scenario": name, "pattern": pattern.source, "driving_width_m": width_m,
                          "spread_width_m": spec.spread_width_m, "throw_distance_m": spec.throw_distance_m,
                          "tray_width_m": test.tray_width_m, "passes": test.passes, **figures,
                          "trays": {"offset_m": test.offset_m.round(4), "total_pct": test.total_pct.round(3),
                                    "in_width": test.in_width},
                          "files": [png]}, indent=True))
        return 0
    print(f"{name}: spinner, {pattern.source} pattern, spread {spec.spread_width_m:g} m, throw "
          f"{spec.throw_distance_m:g} m")
    print(f"  catch trays {test.tray_width_m:g} m across {test.passes} passes to and fro at driving width "
          f"{width_m:g} m")
    print(f"  CV                          {test.cv_pct:6.2f} %  ({int(test.in_width.sum())} trays across the "
          "driving width)")
    print(f"  CV racetrack                {test.cv_racetrack_pct:6.2f} %")
    print(f"  effective width at CV {CV_LIMIT_PCT:g} %  {test.effective_width_m:6.2f} m")
    print(f"  wrote {png}")
    return 0


def _spinner(args):
    """(scenario name, `SpinnerSpec`, `TransversePattern`, driving width m) of ``args.scenario`` with
    its ``--machine`` and ``--set`` keys, loaded and checked whole (`services.cli.options.load_scenario`),
    whose machine must be a spinner: another kind's strips lie side by side and lay a flat rate
    (``cv_pct`` null in ``vrsim run``: not applicable), so it is refused."""
    from vrsim.common import ScenarioError
    from vrsim.services.cli.options import load_scenario

    sc = load_scenario(args)
    implement = sc.implement
    if implement.kind != "spinner":
        raise ScenarioError(f'{sc.source}: [implement] kind: machine pattern needs a spinner '
                            f'(kind = "spinner"), got {implement.kind!r} (its strips lie side by side: '
                            "no spread pattern, cv_pct not applicable)")
    return sc.name, implement.machine, implement.machine.transverse_pattern(), implement.width_m


def _write_picture(test, spec, path: str) -> None:
    """pattern.png: each pass's share and their sum across the trays, the driving width marked."""
    import os

    from vrsim.common import VrsimError
    from vrsim.common.written import written
    from vrsim.services.outputs.plots import figure

    fig = figure(9.0, 4.2, layout="constrained")
    ax = fig.add_subplot()
    across = -test.offset_m  # + to the right of the middle pass, as one looks along its travel
    for j, share in enumerate(test.pass_rate_pct):
        ax.plot(across, share, lw=1, ls="--", label=f"pass {j + 1}")
    ax.step(across, test.total_pct, where="mid", color="k", lw=1.6, label="all passes (trays)")
    half = test.driving_width_m / 2
    ax.axvspan(-half, half, color="tab:green", alpha=0.08, label="driving width")
    ax.axhline(100.0, color="grey", lw=0.8)
    ax.set_xlabel("across the passes, m (0: the middle pass's centre line)")
    ax.set_ylabel("applied, % of the nominal rate")
    ax.set_title(f"spread {spec.spread_width_m:g} m at driving width {test.driving_width_m:g} m: CV "
                 f"{test.cv_pct:.1f} %, effective width {test.effective_width_m:.1f} m at CV 15 %",
                 fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    try:
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    except OSError as exc:
        raise VrsimError(f"--out {os.path.dirname(path)!r}: cannot create the folder "
                         f"({exc.strerror})") from None
    with written(path) as temp:
        fig.savefig(temp, dpi=100, format="png")
