"""Fit the machine's response to its own as-applied log: the twin `vrsim fit` writes as ``machine_fit.toml``.

Each candidate machine is replayed over the log (`services.sim.replay.replay_records`, the control
core a field run uses) and scipy's bounded least squares (``least_squares``, trust region reflective)
moves the candidates to the smallest robust (soft L1: about the absolute beyond 1 % of the
target) difference between the twin's and the logged applied
rate on the records it fits on. The parameters (`FIT_PARAMS`):

* ``dead_time_s``, ``startup_speed_m_s``, ``startup_hold_s`` and ``calibration_error_pct`` of
  ``[response]`` (`vehicle.response.MachineResponse`);
* ``loop_gain``: the machine's controller gains over the scenario's (kp, ki and kd together): how
  fast its loop follows a changing target. The fitted loop's rise and fall time constants (63 % of a
  step up and down, the dead time included) are reported beside it.

Each parameter's uncertainty is one standard deviation from the Jacobian at the optimum (the
residuals' variance times the diagonal of ``(J^T J)^-1``). A parameter the log cannot tell is named
with the reason: no pass start in the fitted records (the preset), or a Jacobian column that moves no
residual, or a standard deviation as wide as its range.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from common import ScenarioError, VrsimError
from controller import build_loop
from maps.log_records import MachineRecords
from services.sim.as_run import resolved_controller
from services.sim.core import machine_plant
from services.sim.replay import Replay, figures, replay_records, working_point_grid
from services.sim.scenario import Scenario
from vehicle.response import MachineResponse

__all__ = ["FIT_PARAMS", "FitParam", "MachineFit", "fit_machine", "fragment_text", "time_constants"]


@dataclass(frozen=True)
class FitParam:
    """A fitted parameter: its name, unit and bounds; `log` fits its logarithm (a scale)."""

    name: str
    unit: str
    lo: float
    hi: float
    log: bool = False


FIT_PARAMS = (FitParam("dead_time_s", "s", 0.0, 4.0), FitParam("startup_speed_m_s", "m/s", 0.0, 12.0),
              FitParam("startup_hold_s", "s", 0.0, 15.0), FitParam("calibration_error_pct", "%", -20.0, 20.0),
              FitParam("loop_gain", "-", 0.02, 20.0, log=True))
PRESET = ("startup_speed_m_s", "startup_hold_s")
MAX_EVALUATIONS = 60          # replays per start of the optimizer
ROBUST_SCALE = 0.01           # residuals (share of the target) beyond this weigh as their size
UNIDENTIFIABLE_SPREAD = 0.25  # a standard deviation over this share of the bounds: not identified
STEP_SETTLE_S = 60.0          # a simulated step runs this long for the time constants


@dataclass
class MachineFit:
    """What `fit_machine` found.

    Attributes
    ----------
    values, std : dict
        Each fitted parameter's value and one standard deviation (None: not identifiable), in its unit.
    not_identified : dict
        Parameter -> why this log cannot tell it (its value is then the scenario's, kept).
    rise_time_constant_s, fall_time_constant_s : float
        The fitted loop's time to 63 % of a step up (down) of the target, the dead time included [s].
    scenario : Scenario
        The fitted machine (the base scenario with the fitted values).
    fitted, judged : dict
        The twin's figures against the log on the records fitted on, and on the records held out (empty
        without a hold-out), with the target's as the baseline (`services.sim.replay.figures`' keys).
    default : dict
        The unfitted machine's figures on the same records (``fitted`` and ``judged`` parts).
    converged : bool
    evaluations : int
        Replays run.
    """

    values: dict
    std: dict
    not_identified: dict
    rise_time_constant_s: float
    fall_time_constant_s: float
    scenario: Scenario
    fitted: dict
    judged: dict
    default: dict
    converged: bool
    evaluations: int


def fit_machine(records: MachineRecords, scenario: Scenario,
                fit_rows: np.ndarray | None = None) -> MachineFit:
    """Fit `scenario`'s machine to `records` on the rows `fit_rows` (bool (n,); default all), judging on
    the others (see the module docstring)."""
    fit_rows = np.ones(records.rows, bool) if fit_rows is None else np.asarray(fit_rows, bool)
    base = _base(scenario, records)
    first = replay_records(records, base)
    use = first.counts & fit_rows & np.isfinite(first.simulated)
    if use.sum() < 10:
        raise ScenarioError(f"{records.source}: {int(use.sum())} records to fit on (moving, a section open, "
                            "applied rate logged): too few to fit a machine")
    free = [p for p in FIT_PARAMS if not (p.name in PRESET and not _has_pass_start(first, use))]
    scale = float(np.nanmedian(np.abs(records.target[use]))) or 1.0
    counter = [0]

    def residuals(z):
        counter[0] += 1
        sim = replay_records(records, _candidate(base, free, z)).simulated[use]
        return np.nan_to_num((sim - records.applied[use]) / scale, nan=0.0)

    best = _optimize(residuals, free, base)
    fitted = _candidate(base, free, best.x)
    final = replay_records(records, fitted)
    values, std, why = _uncertainty(best, free, base)
    for p in FIT_PARAMS:
        if p not in free:
            why[p.name] = "no pass start (sections opening) in the records fitted on"
    rise_s, fall_s = time_constants(fitted, records)
    return MachineFit(values=values, std=std, not_identified=why, rise_time_constant_s=rise_s,
                      fall_time_constant_s=fall_s, scenario=fitted,
                      fitted=_part(final, use), judged=_part(final, first.counts & ~fit_rows),
                      default={"fitted": _part(first, use), "judged": _part(first, first.counts & ~fit_rows)},
                      converged=bool(best.success), evaluations=counter[0])


def _base(scenario: Scenario, records: MachineRecords) -> Scenario:
    """`scenario` with its controller's gains as numbers (the loop gain scales them)."""
    at_rest = dataclasses.replace(scenario, response=MachineResponse())
    plant = machine_plant(at_rest, _grid_for(scenario, records))
    cfg = resolved_controller(scenario.controller, plant, scenario.timing.control_period_s)
    return dataclasses.replace(scenario, controller=cfg)


def _grid_for(scenario: Scenario, records: MachineRecords):
    from maps.units import convert_rate
    rate = convert_rate(records.target, records.unit or "kg/ha", "kg/ha", scenario.product.density_kg_l)
    return working_point_grid(records, rate)


def _has_pass_start(rp: Replay, use: np.ndarray) -> bool:
    return bool(((rp.event == "pass_start") & use).any())


def _candidate(base: Scenario, free, z) -> Scenario:
    """The machine at optimizer coordinates `z` (one per free parameter)."""
    values = {p.name: _value(p, v) for p, v in zip(free, z, strict=True)}
    gain = values.pop("loop_gain", 1.0)
    response = dataclasses.replace(base.response, **values)
    cfg = base.controller
    scaled = {k: getattr(cfg, k) * gain for k in ("kp", "ki", "kd") if getattr(cfg, k) is not None}
    if not scaled and gain != 1.0:
        raise ScenarioError(f"{base.source}: [controller] kind {cfg.kind!r} has no gains to fit; fit a "
                            "PID-family controller")
    return dataclasses.replace(base, response=response, controller=dataclasses.replace(cfg, **scaled))


def _value(p: FitParam, z: float) -> float:
    return float(math.exp(z)) if p.log else float(z)


def _coord(p: FitParam, value: float) -> float:
    return math.log(value) if p.log else value


def _start(p: FitParam, base: Scenario) -> float:
    if p.name == "loop_gain":
        return 1.0
    if p.name == "startup_speed_m_s":
        return base.tractor.working_speed_m_s
    if p.name == "startup_hold_s":
        return 3.0
    if p.name == "dead_time_s":
        return 0.5
    return getattr(base.response, p.name)


def _optimize(residuals, free, base):
    from scipy.optimize import least_squares

    x0 = np.array([_coord(p, _start(p, base)) for p in free])
    lo = np.array([_coord(p, p.lo) for p in free])
    hi = np.array([_coord(p, p.hi) for p in free])
    step = np.array([0.05 if p.log else 0.02 * (p.hi - p.lo) for p in free])
    best = None
    for x in _starts(residuals, free, x0, lo, hi):
        try:
            found = least_squares(residuals, x, bounds=(lo, hi), x_scale=(hi - lo) / 4, loss="soft_l1",
                                  f_scale=ROBUST_SCALE, diff_step=step / np.maximum(np.abs(x), 1e-3),
                                  max_nfev=MAX_EVALUATIONS, xtol=1e-4, ftol=1e-6)
        except VrsimError:
            raise
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise ScenarioError(f"the fit failed: {exc}") from None
        if best is None or found.cost < best.cost:
            best = found
    return best


def _starts(residuals, free, x0, lo, hi) -> list[np.ndarray]:
    """Where the optimizer starts: the best two of a coarse grid over the preset and the dead time
    (a pass start's error is flat where the preset speed is below the tractor's: a gradient finds no
    way out there), by their robust cost."""
    names = [p.name for p in free]
    grid = [np.clip(x0, lo, hi)]
    speeds = (0.7, 1.0, 1.4) if "startup_speed_m_s" in names else (None,)
    for factor in speeds:
        for hold_s, dead_s in ((2.0, 0.2), (5.0, 1.0), (10.0, 0.5)):
            x = x0.copy()
            if factor is not None:
                x[names.index("startup_speed_m_s")] = x0[names.index("startup_speed_m_s")] * factor
                x[names.index("startup_hold_s")] = hold_s
            if "dead_time_s" in names:
                x[names.index("dead_time_s")] = dead_s
            grid.append(np.clip(x, lo, hi))
    cost = [_robust_cost(residuals(x)) for x in grid]
    return [grid[i] for i in np.argsort(cost)[:2]]


def _robust_cost(r: np.ndarray) -> float:
    """least_squares' soft L1 cost at `ROBUST_SCALE`."""
    z = (r / ROBUST_SCALE) ** 2
    return float(np.sum(2 * (np.sqrt(1 + z) - 1)))


def _uncertainty(best, free, base) -> tuple[dict, dict, dict]:
    """Values, standard deviations and the parameters not identified, from the optimum's Jacobian."""
    J, r = np.asarray(best.jac, float), np.asarray(best.fun, float)
    dof = max(1, r.size - len(free))
    s2 = float(r @ r) / dof
    cov = np.linalg.pinv(J.T @ J) * s2
    values, std, why = {}, {}, {}
    for i, p in enumerate(free):
        value = _value(p, best.x[i])
        sd_z = math.sqrt(max(cov[i, i], 0.0))
        sd = value * sd_z if p.log else sd_z   # a log coordinate's spread, to first order
        span = (_coord(p, p.hi) - _coord(p, p.lo))
        values[p.name] = value
        if not np.any(J[:, i]):
            why[p.name] = "changing it moves no record's rate"
            std[p.name] = None
        elif sd_z > UNIDENTIFIABLE_SPREAD * span:
            why[p.name] = f"its standard deviation ({sd:.3g} {p.unit}) spans its range"
            std[p.name] = None
        else:
            std[p.name] = sd
    for p in FIT_PARAMS:
        if p not in free:
            values[p.name] = 1.0 if p.name == "loop_gain" else getattr(base.response, p.name)
            std[p.name] = None
    return values, std, why


def _part(rp: Replay, rows: np.ndarray) -> dict:
    """The figures of replay `rp` over `rows`, overall and per event class."""
    return figures(rp.records.applied, rp.simulated, rp.records.target, rp.event, rows)


def time_constants(scenario: Scenario, records: MachineRecords) -> tuple[float, float]:
    """The machine's loop's time to 63 % of a step of its target up (from half to the working flow) and
    down (back to half), the dead time included [s]: its rise and fall time constants."""
    grid = _grid_for(scenario, records)
    plant = machine_plant(scenario, grid)
    period_s = scenario.timing.control_period_s
    loop = build_loop(plant, scenario.controller, control_period_s=period_s,
                      plant_step_s=scenario.timing.plant_step_s)
    flow = _working_flow(plant)
    n = int(STEP_SETTLE_S / period_s)
    target = np.concatenate([np.full(n, 0.5 * flow), np.full(n, flow), np.full(n, 0.5 * flow)])
    out = np.asarray(loop.run(target).shaft_rev).reshape(-1) * 60.0 / period_s
    return _t63(out[n - 1:2 * n], period_s), _t63(out[2 * n - 1:], period_s)


def _working_flow(plant) -> float:
    """A target inside the loop's range: three quarters of its highest [its units per minute]."""
    return 0.75 * plant.shaft_rpm_max if math.isfinite(plant.shaft_rpm_max) else 1.0


def _t63(y: np.ndarray, period_s: float) -> float:
    start, end = float(y[0]), float(np.median(y[-len(y) // 5:]))
    if end == start:
        return float("nan")
    crossed = np.flatnonzero((y - start) / (end - start) >= 0.632)
    return float(crossed[0] * period_s) if crossed.size else float("nan")


def fragment_text(fit: MachineFit, source: str) -> str:
    """``machine_fit.toml``: the fitted machine as a fragment of scenario tables (`--machine FILE`)."""
    from services.sim.machines.keys import implement_table
    from services.sim.scenario import toml_value

    sc = fit.scenario
    implement = {k: v for k, v in implement_table(sc.implement).items()
                 if k not in ("section_control", "delivery_delay_s") and v is not None}
    cfg = sc.controller
    controller = {"kind": cfg.kind, "gains": "manual", "kp": cfg.kp, "ki": cfg.ki, "kd": cfg.kd}
    product = {k: getattr(sc.product, k) for k in ("form", "density_kg_l")
               if getattr(sc.product, k) is not None}
    tables = {"implement": implement, "product": product, "controller": controller,
              "response": dataclasses.asdict(sc.response)}
    lines = [f"# The machine of {source}, fitted by vrsim fit: give it with --machine to vrsim run,",
             "# replay, compare and tune. [response] and the controller's gains are fitted; the rest is",
             "# the machine that was replayed."]
    for name, table in tables.items():
        lines += ["", f"[{name}]"]
        lines += [f"{k} = {toml_value(v)}" for k, v in table.items() if v is not None]
    return "\n".join(lines) + "\n"
