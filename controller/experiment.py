"""The paper's experiment on vrsim's model: ultimate gain, then P, PI and PID step responses with the
paper's literal gains and with textbook Ziegler-Nichols gains, side by side with the paper's figures,
and each loop's margins, crossover and bandwidth (`controller.analysis`, key ``loop``).

`run_paper` returns the summary (the dict `vrsim paper --json` prints) and the responses to plot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vrsim.controller import liang2013
from vrsim.controller.analysis import analyze_loop
from vrsim.controller.config import ControllerConfig
from vrsim.controller.gains import TERMS, PidGains, paper_gains, ziegler_nichols
from vrsim.controller.metrics import step_metrics
from vrsim.controller.plant import PlantParams, assumptions, unlimited
from vrsim.controller.simulate import simulate
from vrsim.controller.tuning import fit_sensor, relay_autotune, ultimate_gain_experiment

STEP_RPM = 100.0
DURATION_S = 20.0
MATCH_REL = 0.10    # a figure counts as reproduced within 10% of the paper's

EXPERIMENT_ASSUMPTIONS = {
    "step_rpm": (STEP_RPM, "rpm", "Metering-shaft step from rest; the paper does not give its size. The "
                 "responses are simulated without current limits, as the paper's Simulink model (Fig. 4) "
                 "has none, so the size only scales them."),
    "duration_s": (DURATION_S, "s", "Simulated time per response, over 3x the paper's longest settling."),
    "control_period_s": (liang2013.SAMPLE_S, "s", "The paper's sampling period T."),
    "plant_step_s": (0.001, "s", "Exact ZOH plant step; the paper's bench sampled at 1 kHz. Metrics use "
                     "these 1 ms samples."),
    "computation_delay_s": (0.0, "s", "u(n) acts at the instant e(n) is sampled, as in a Simulink discrete "
                            "PID; all loop delay sits in sensor_delay_s."),
    "paper_P_PI_gains": ("Kp=0.573; PI: A=Kp(1+Ki), B=Kp", "-", "The paper prints only its PID set; P "
                         "uses its Kp and PI its Kp and Ki with Kd = 0 (eq. 16)."),
    "ultimate_labels": ("Ku=0.955 gain, Tu=0.31 s period", "-", "The paper swaps the labels (Km 'period' = "
                        "0.955, Tm 'gain' = 0.31 s); only this reading gives its Kp = 0.6 Km = 0.573."),
}


@dataclass(frozen=True)
class PaperRun:
    """Summary dict plus the 1 kHz responses, keyed "P", "PI", "PID" and "textbook P" etc. [rpm]."""

    summary: dict
    t_s: np.ndarray
    responses: dict[str, np.ndarray]


def _finite(x) -> float | None:
    x = float(x)
    return (0.0 if abs(x) < 1e-9 else x) if math.isfinite(x) else None


def _close(ours, paper) -> bool:
    return ours is not None and paper is not None and abs(ours - paper) <= MATCH_REL * abs(paper)


def _loop_figures(plant: PlantParams, terms: str, gains: PidGains) -> dict:
    """Margins, crossover and bandwidth of the PID loop with these gains (`analysis.LoopAnalysis`)."""
    cfg = ControllerConfig(kind=terms, gains="manual", kp=gains.kp, ki=gains.ki or None, kd=gains.kd or None)
    return analyze_loop(plant, cfg, liang2013.SAMPLE_S).to_dict()


def _entry(kind: str, gains: PidGains, metrics, i: int, mean_overshoot: float, plant: PlantParams) -> dict:
    paper = liang2013.STEP[kind]
    a, b, c = gains.incremental(liang2013.SAMPLE_S)
    row = metrics.row(i)
    ours_os, ours_ts = _finite(row["overshoot_pct"]), _finite(row["settling_2pct_s"])
    return {
        "overshoot_pct": ours_os, "settling_s": ours_ts,
        "paper_overshoot_pct": paper["overshoot_pct"], "paper_settling_s": paper["settling_s"],
        "overshoot_reproduced": _close(ours_os, paper["overshoot_pct"]),
        "settling_reproduced": _close(ours_ts, paper["settling_s"]),
        "overshoot_pct_50ms_mean": _finite(mean_overshoot),
        "settling_5pct_s": _finite(row["settling_5pct_s"]), "rise_s": _finite(row["rise_s"]),
        "steady_state_error_rpm": _finite(row["steady_state_error"]),
        "iae_rpm_s": _finite(row["iae"]), "itae_rpm_s2": _finite(row["itae"]),
        "gains": {"kp": gains.kp, "ki_per_s": gains.ki, "kd_s": gains.kd, "A": a, "B": b, "C": c},
        "loop": _loop_figures(plant, kind, gains),
    }


def _findings(summary: dict) -> list[str]:
    u = summary["ultimate"]
    lines = [
        f"Ku and Tu: reproduced by construction. vrsim's simulated ultimate-gain experiment gives "
        f"Ku = {u['Ku']:.4g}, Tu = {u['Tu_s']:.4g} s; the sensor delay and gain were fitted to exactly these "
        f"two numbers and to nothing else.",
        f"The paper's transfer functions alone cannot give Tu = 0.31 s: without the fitted delay the 50 ms "
        f"P loop oscillates at {u['without_delay_Tu_s']:.3g} s (its resonances at 184 and 335 rad/s lie "
        f"above the 62.8 rad/s Nyquist frequency).",
    ]
    pi, pid = summary["PI"], summary["PID"]
    lines.append(
        f"PI vs PID: the paper's printed C = {liang2013.C} (its Kd = 0.125 Kp T Tu instead of Td/T) makes "
        f"the derivative term {liang2013.C / liang2013.A:.2%} of A, so its PID behaves like its PI "
        f"(vrsim: {pi['overshoot_pct']:.4g}% vs {pid['overshoot_pct']:.4g}%); the paper's 53.21% vs 27.92% "
        f"cannot come from its printed gains. Its Ki is also applied with Kp twice (A = Kp(1 + Ki + Kd) with "
        f"Ki = Kp T/(0.5 Tu)).")
    for kind in TERMS:
        e = summary[kind]
        got = [name for name, ok in (("overshoot", e["overshoot_reproduced"]),
                                     ("settling time", e["settling_reproduced"])) if ok]
        verdict = f"reproduces its {' and '.join(got)}" if got else "reproduces neither figure"
        lines.append(
            f"{kind} with the paper's gains: vrsim {verdict} (vrsim {e['overshoot_pct']:.4g}% / "
            f"{e['settling_s']} s vs paper {e['paper_overshoot_pct']}% / {e['paper_settling_s']} s). These "
            f"figures were not fitted; the difference is what the model predicts, not tuned away.")
    lines.append(
        "Overshoot at 1 kHz includes the motor's lightly damped resonance (zh = 0.12) rung by each 50 ms "
        "current step; overshoot_pct_50ms_mean is the same response averaged over each control period.")
    tb = summary["textbook"]["PID"]
    lines.append(
        f"Textbook Ziegler-Nichols PID (Td = Tu/8, C = {tb['gains']['C']:.3g}) on this delay-dominated loop: "
        f"{tb['overshoot_pct']:.4g}% overshoot, settling {tb['settling_s']} s; the textbook PI "
        f"({summary['textbook']['PI']['overshoot_pct']:.3g}% overshoot) is the best-damped of the six.")
    return lines


def run_paper(plant: PlantParams | None = None, step_rpm: float = STEP_RPM,
              duration_s: float = DURATION_S) -> PaperRun:
    """Run the paper's experiment on `plant` (default: `PlantParams()`); pure and deterministic."""
    plant = plant or PlantParams()
    T, h = liang2013.SAMPLE_S, 0.001
    ult = ultimate_gain_experiment(plant, T, h)
    relay = relay_autotune(plant, T, h)
    no_delay = ultimate_gain_experiment(replace(plant, sensor_delay_s=0.0), T, h)
    fit = fit_sensor(plant, liang2013.KU, liang2013.TU_S, T)
    literal = [paper_gains(k) for k in TERMS]
    textbook = [ziegler_nichols(k, liang2013.KU, liang2013.TU_S) for k in TERMS]
    res = simulate(unlimited(plant), literal + textbook, step_rpm, duration_s, T, h)
    metrics = step_metrics(res.t_s, res.shaft_rpm, step_rpm)
    mean_rpm = np.hstack([np.zeros((len(literal) * 2, 1)), (res.shaft_rev * 60.0 / T).T])
    mean_metrics = step_metrics(np.arange(mean_rpm.shape[1]) * T, mean_rpm, step_rpm)
    ran = {"step_rpm": step_rpm, "duration_s": duration_s}  # the values used, not the defaults
    entries = [_entry(k, g, metrics, i, mean_metrics.overshoot_pct[i], plant)
               for i, (k, g) in enumerate(zip(TERMS * 2, literal + textbook, strict=True))]
    summary = {
        "ultimate": {
            "Ku": ult.ku, "Tu_s": ult.tu_s, "paper_Ku": liang2013.KU, "paper_Tu_s": liang2013.TU_S,
            "Ku_error_pct": 100 * (ult.ku / liang2013.KU - 1),
            "Tu_error_pct": 100 * (ult.tu_s / liang2013.TU_S - 1),
            "fitted_sensor_delay_s": fit.sensor_delay_s,
            "fitted_sensor_gain_v_per_rpm": float(fit.sensor_gain_v_per_rpm),
            "without_delay_Ku": no_delay.ku, "without_delay_Tu_s": no_delay.tu_s,
            "relay_Ku": relay.ku, "relay_Tu_s": relay.tu_s,
        },
        **{k: e for k, e in zip(TERMS, entries[:3], strict=True)},
        "textbook": {k: e for k, e in zip(TERMS, entries[3:], strict=True)},
        "paper_formulas": liang2013.formula_coefficients(),
        "assumptions": {**assumptions(plant), **{k: {"value": ran.get(k, v), "unit": u, "why": w}
                                                   for k, (v, u, w) in EXPERIMENT_ASSUMPTIONS.items()}},
    }
    summary["findings"] = _findings(summary)
    names = [*TERMS, *(f"textbook {k}" for k in TERMS)]
    return PaperRun(summary=summary, t_s=res.t_s, responses=dict(zip(names, res.shaft_rpm, strict=True)))


def paper_experiment(plant: PlantParams | None = None) -> dict:
    """The dict `vrsim paper --json` prints (see `run_paper`)."""
    return run_paper(plant).summary
