"""What `vrsim paper` writes: the side-by-side text table and step_responses.png."""

from __future__ import annotations

from vrsim.common.written import written

PLOT_S = 8.0  # seconds of response shown: all of the paper's settling times fit


def _fmt(x, spec=".4g") -> str:
    return "-" if x is None else format(x, spec)


def table(summary: dict) -> str:
    """The side-by-side text report of `summary` (as returned by `controller.paper_experiment`)."""
    u = summary["ultimate"]
    lines = [
        "Liang et al. 2013, valve-controlled hydraulic motor: paper vs vrsim",
        "",
        f"{'ultimate gain experiment':<28}{'paper':>10}{'vrsim':>10}",
        f"{'  Ku [V/V]':<28}{u['paper_Ku']:>10.4g}{u['Ku']:>10.4g}",
        f"{'  Tu [s]':<28}{u['paper_Tu_s']:>10.4g}{u['Tu_s']:>10.4g}",
        f"  relay auto-tune on the model: Ku {u['relay_Ku']:.4g}, Tu {u['relay_Tu_s']:.4g} s; "
        f"without the fitted delay: Ku {u['without_delay_Ku']:.4g}, Tu {u['without_delay_Tu_s']:.4g} s",
        "",
        f"{'step response (2% settling)':<28}{'overshoot %':>24}{'settling s':>24}",
        f"{'':<28}{'paper':>8}{'vrsim':>8}{'50ms':>8}{'paper':>12}{'vrsim':>12}",
    ]
    for label, group in (("paper gains", summary), ("textbook Z-N", summary["textbook"])):
        for kind in ("P", "PI", "PID"):
            e = group[kind]
            lines.append(f"  {label + ' ' + kind:<26}{_fmt(e['paper_overshoot_pct'], '.2f'):>8}"
                         f"{_fmt(e['overshoot_pct'], '.2f'):>8}{_fmt(e['overshoot_pct_50ms_mean'], '.2f'):>8}"
                         f"{_fmt(e['paper_settling_s'], '.3f'):>12}{_fmt(e['settling_s'], '.3f'):>12}")
    lines += ["", "(50ms: overshoot of the speed averaged over each control period)", ""]
    lines += _loop_table(summary)
    lines += ["", "Findings:"]
    lines += [f"- {f}" for f in summary["findings"]]
    lines += ["", "Assumptions (value, unit):"]
    lines += [f"- {name} = {a['value']} {a['unit']}: {a['why']}"
              for name, a in summary["assumptions"].items()]
    return "\n".join(lines)


def _loop_table(summary: dict) -> list[str]:
    """Each controller's loop margins, crossover and bandwidth (``summary[kind]["loop"]``)."""
    lines = [f"{'loop margins (T = 50 ms)':<28}{'gain margin':>16}{'phase margin':>14}"
             f"{'crossover':>12}{'bandwidth':>12}",
             f"{'':<28}{'x (dB)':>16}{'deg':>14}{'rad/s':>12}{'rad/s':>12}"]
    for label, group in (("paper gains", summary), ("textbook Z-N", summary["textbook"])):
        for kind in ("P", "PI", "PID"):
            loop = group[kind]["loop"]
            margin = f"{_fmt(loop['gain_margin'], '.3f')} ({_fmt(loop['gain_margin_db'], '.1f')})"
            phase, cross = _fmt(loop["phase_margin_deg"], ".1f"), _fmt(loop["crossover_rad_s"], ".3f")
            lines.append(f"  {label + ' ' + kind:<26}{margin:>16}{phase:>14}{cross:>12}"
                         f"{_fmt(loop['bandwidth_rad_s'], '.3f'):>12}"
                         + ("" if loop["closed_loop_stable"] else "  unstable"))
    return lines


def plot(run, path: str) -> None:
    """Write the three step responses (like the paper's Figs. 5-7) to `path` (PNG)."""
    from matplotlib.figure import Figure  # Agg canvas, without pyplot's global state

    fig = Figure(figsize=(9, 10))
    axes = fig.subplots(3, 1, sharex=True)
    shown = run.t_s <= PLOT_S
    t = run.t_s[shown]
    for ax, kind in zip(axes, ("P", "PI", "PID"), strict=True):
        e = run.summary[kind]
        ax.plot(t, run.responses[kind][shown], lw=0.8, label=f"paper gains ({_fmt(e['overshoot_pct'])}% / "
                f"{_fmt(e['settling_s'])} s)")
        tb = run.summary["textbook"][kind]
        ax.plot(t, run.responses[f"textbook {kind}"][shown], lw=0.8, alpha=0.8,
                label=f"textbook Z-N ({_fmt(tb['overshoot_pct'])}% / {_fmt(tb['settling_s'])} s)")
        ax.axhline(run.summary["assumptions"]["step_rpm"]["value"], color="k", lw=0.6, ls="--")
        ax.set_title(f"{kind}: paper reports {e['paper_overshoot_pct']}% overshoot, "
                     f"{e['paper_settling_s']} s settling")
        ax.set_ylabel("shaft speed [rpm]")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlim(0, PLOT_S)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    with written(path) as temp:
        fig.savefig(temp, dpi=110)
