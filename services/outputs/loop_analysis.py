"""What `vrsim controller analyze` writes and prints: bode.png, step.png and the text report of a
`services.sim.analyze.ControllerReport`."""

from __future__ import annotations

import math
import os

import numpy as np

from vrsim.common import VrsimError
from vrsim.common.written import staged

STEP_RPM = 100.0       # a shaft's step in step.png, from rest, as in the paper's bench test
STEP_DURATION_S = 5.0


def _step_size(report) -> float:
    """The step of step.png, in the loop's unit: `STEP_RPM` for a shaft; for another loop (a sprayer's
    flow, whose range may end below 100 L/min) the response's high target, 60 % of its range."""
    return STEP_RPM if report.unit == "rpm" else report.response.high_rpm


def _fmt(x, spec: str = ".3g") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def write_pictures(report, out_dir: str) -> list[str]:
    """Write ``bode.png`` (open loop with its margins; only for a linear controller) and ``step.png``
    (a step from rest, `_step_size`: the simulated loop at 1 ms with saturation, and the linear closed
    loop if there is one) into `out_dir`; return their paths."""
    names = ["bode.png", "step.png"] if report.loop is not None else ["step.png"]
    with staged(out_dir) as stage:  # both pictures or neither
        if report.loop is not None:
            _save(_bode(report.loop), os.path.join(stage, "bode.png"))
        _save(_step(report), os.path.join(stage, "step.png"))
    return [os.path.join(out_dir, name) for name in names]


def _save(fig, path: str) -> None:
    try:
        fig.savefig(path, dpi=110, bbox_inches="tight")
    except OSError as exc:
        raise VrsimError(f"cannot write {path} ({exc.strerror})") from None


def _bode(loop):
    import control
    from matplotlib.figure import Figure  # Agg canvas, without pyplot's global state

    w = np.geomspace(0.1, math.pi / loop.control_period_s, 600)
    resp = control.frequency_response(loop.open_loop, w).complex.ravel()
    fig = Figure(figsize=(7, 6))
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    ax_m.semilogx(w, 20 * np.log10(np.abs(resp)))
    ax_m.axhline(0, color="grey", lw=0.8)
    ax_m.set_ylabel("|L| [dB]")
    ax_p.semilogx(w, np.degrees(np.unwrap(np.angle(resp))))
    ax_p.axhline(-180, color="grey", lw=0.8)
    ax_p.set_ylabel("phase of L [deg]")
    ax_p.set_xlabel("frequency [rad/s]")
    for ax, x in ((ax_m, loop.phase_crossover_rad_s), (ax_p, loop.crossover_rad_s)):
        if math.isfinite(x):
            ax.axvline(x, color="tab:red", ls="--", lw=0.8)
    ax_m.set_title(f"{loop.kind}: gain margin {_fmt(loop.gain_margin_db, '.1f')} dB, phase margin "
                   f"{_fmt(loop.phase_margin_deg, '.0f')} deg, crossover "
                   f"{_fmt(loop.crossover_rad_s, '.2f')} rad/s")
    return fig


def _step(report):
    import control
    from matplotlib.figure import Figure

    from vrsim.controller.simulate import simulate

    timing = report.scenario.timing
    t, step, unit = timing.control_period_s, _step_size(report), report.unit
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    sim = simulate(report.plant, report.controller, step, STEP_DURATION_S, t, timing.plant_step_s)
    what = "shaft" if unit == "rpm" else report.quantity
    ax.plot(sim.t_s, sim.shaft_rpm[0], lw=0.8, label=f"simulated {what}, {timing.plant_step_s * 1e3:g} ms, "
            "saturating")
    if report.loop is not None:
        lin = control.step_response(report.loop.closed_loop, T=np.arange(0.0, STEP_DURATION_S, t))
        ax.step(lin.time, step * np.ravel(lin.outputs), where="post", label="linear loop, sensor reading")
    ax.axhline(step, color="grey", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{report.quantity} [{unit}]")
    ax.set_title(f"{report.controller.kind}: {step:.4g} {unit} step from rest")
    ax.legend()
    return fig


def text(report) -> str:
    """The readable report ``vrsim controller analyze`` prints."""
    cfg, loop, r, la = report.controller, report.loop, report.response, report.look_ahead
    alike = f", one of {report.drives} alike" if report.drives > 1 else ""
    lines = [f"vrsim controller analyze: {report.scenario.name}, controller kind {cfg.kind}",
             f"  machine {report.machine}: the loop of its {report.quantity} [{report.unit}]{alike}"]
    if loop is None:
        lines.append(f"  loop: {report.no_loop_reason}")
    else:
        stable = "stable" if loop.closed_loop_stable else "UNSTABLE"
        lines += [
            f"  loop L(z) = Ka Ks C(z) G(z) at T = {loop.control_period_s:g} s, sensor delay "
            f"{loop.delay_periods} periods; closed loop {stable}",
            f"    gain margin            {_fmt(loop.gain_margin, '.3f')} "
            f"({_fmt(loop.gain_margin_db, '.2f')} dB) at {_fmt(loop.phase_crossover_rad_s, '.3f')} rad/s",
            f"    phase margin           {_fmt(loop.phase_margin_deg, '.1f')} deg at the crossover "
            f"{_fmt(loop.crossover_rad_s, '.3f')} rad/s",
            f"    closed-loop bandwidth  {_fmt(loop.bandwidth_rad_s, '.3f')} rad/s "
            "(-3 dB, target -> reading)",
        ]
    lines += [
        f"  response, per-period {report.quantity}, {r.low_rpm:.4g} <-> {r.high_rpm:.4g} {report.unit}:"
        f"{'up':>10}{'down':>10}",
        *(f"    {label:<44}{_fmt(getattr(r.up, key), '.3f'):>10}{_fmt(getattr(r.down, key), '.3f'):>10}"
          for label, key in (("t50 [s]", "t50_s"), ("t63 [s]", "t63_s"), ("t90 [s]", "t90_s"),
                             ("mean lag [s]", "mean_lag_s"))),
        f"  look-ahead: delivery delay {la['delivery_delay_s']:.3f} s + GNSS fix age {la['fix_age_s']:.3f} s "
        f"+ mean lag {la['mean_lag_s']:.3f} s = {la['auto_s']:.3f} s with look_ahead_s = \"auto\"",
        f"    this scenario starts at {la['used_s']:.3f} s"
        + (f", auto-tuned with gain {la['tune']:g}" if la["tune"] else ""),
    ]
    return "\n".join(lines)
