"""Fit the machine's response to its own as-applied log: the twin `vrsim fit` writes as ``machine_fit.toml``.

Each candidate machine is replayed over the log (`services.sim.replay.replay_records`, the control
core a field run uses) and scipy's bounded least squares (``least_squares``, trust region reflective)
moves the candidates to the smallest robust (soft L1: about the absolute beyond 1 % of the
target) difference between the twin's and the logged applied
rate on the records it fits on. The parameters (`FIT_PARAMS`):

* ``dead_time_s``, ``startup_speed_m_s``, ``startup_hold_s``, ``opening_peak_pct``,
  ``opening_time_constant_s`` and ``calibration_error_pct`` of ``[response]``
  (`vehicle.response.MachineResponse`);
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
import itertools
import math
from dataclasses import dataclass

import numpy as np

from vrsim.common import ScenarioError, VrsimError
from vrsim.controller import build_loop
from vrsim.maps.log_records import MachineRecords
from vrsim.services.sim.as_run import resolved_controller
from vrsim.services.sim.core import machine_plant
from vrsim.services.sim.replay import Replay, figures, replay_records, working_point_grid
from vrsim.services.sim.scenario import Scenario
from vrsim.vehicle.response import MachineResponse

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
              FitParam("startup_hold_s", "s", 0.0, 15.0), FitParam("opening_peak_pct", "%", -100.0, 300.0),
              FitParam("opening_time_constant_s", "s", 0.0, 15.0),
              FitParam("calibration_error_pct", "%", -20.0, 20.0),
              FitParam("loop_gain", "-", 0.02, 20.0, log=True))
PASS_START = ("startup_speed_m_s", "startup_hold_s", "opening_peak_pct", "opening_time_constant_s")
MAX_EVALUATIONS = 25          # optimizer steps per stage (each also replays once per parameter)
DEAD_TIME_GRID_S = (0.0, 0.3, 0.7, 1.2, 2.0, 3.0)   # dead times tried before the loop's least squares
PRESET_GRID = ((0.5, 0.75, 1.0, 1.25, 1.6, 2.0), (1.0, 2.0, 3.5, 5.0, 8.0, 12.0))   # x working speed, s
OPENING_GRID = ((-60.0, 0.0, 30.0, 80.0, 200.0), (0.5, 1.5, 4.0))   # peak %, time constant s
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
    the others (see the module docstring).

    In stages: the loop (dead time, offset, loop gain) on the records away from pass starts with no
    preset; the preset on a grid of speeds and holds, on the pass starts' records with that loop (the
    pass-start error is flat wherever the preset speed is below the tractor's, and rugged in the hold:
    a gradient alone stops in the first dip); then everything together, from there or from the usual
    machine, whichever the log fits better (by the robust cost on the records fitted on)."""
    fit_rows = np.ones(records.rows, bool) if fit_rows is None else np.asarray(fit_rows, bool)
    base = _base(scenario, records)
    first = replay_records(records, base)
    use = first.counts & fit_rows & np.isfinite(first.simulated)
    if use.sum() < 10:
        raise ScenarioError(f"{records.source}: {int(use.sum())} records to fit on (moving, a section open, "
                            "applied rate logged): too few to fit a machine")
    problem = _Problem(records, base, use)
    starts = use & (first.event == "pass_start")
    loop = [p for p in FIT_PARAMS if p.name not in PASS_START]
    free = list(FIT_PARAMS) if starts.any() else loop
    usual = {p.name: _start(p, base) for p in FIT_PARAMS}
    if not starts.any():
        usual.update({name: 0.0 for name in PASS_START})
    staged = dict(usual)
    away = use & ~starts
    if away.sum() >= 10:
        staged.update(problem.grid(staged, away, {"dead_time_s": DEAD_TIME_GRID_S}, preset_off=True))
        staged.update(problem.solve(loop, staged, away, preset_off=True).values)
    if starts.any():
        staged.update(problem.pass_start_grid(staged, starts))
    # All together, from the staged values or the usual machine, whichever the log fits better.
    start = min((staged, usual), key=lambda values: _robust_cost(problem.residuals(values, use)))
    best = problem.solve(free, start, use)
    fitted = _candidate(base, best.values)
    final = replay_records(records, fitted)
    why = best.not_identified
    for p in FIT_PARAMS:
        if p not in free:
            why[p.name] = "no pass start (sections opening) in the records fitted on"
            best.values[p.name] = 0.0
    rise_s, fall_s = time_constants(fitted, records)
    return MachineFit(values=best.values, std=best.std, not_identified=why, rise_time_constant_s=rise_s,
                      fall_time_constant_s=fall_s, scenario=fitted,
                      fitted=_part(final, use), judged=_part(final, first.counts & ~fit_rows),
                      default={"fitted": _part(first, use), "judged": _part(first, first.counts & ~fit_rows)},
                      converged=best.converged, evaluations=problem.evaluations)


@dataclass
class _Solved:
    values: dict
    std: dict
    not_identified: dict
    converged: bool
    cost: float


class _Problem:
    """The replays of one log's candidate machines, counted, as residuals of the optimizer."""

    def __init__(self, records: MachineRecords, base: Scenario, use: np.ndarray):
        self.records, self.base = records, base
        self.scale = float(np.nanmedian(np.abs(records.target[use]))) or 1.0
        self.evaluations = 0

    def residuals(self, values: dict, rows: np.ndarray) -> np.ndarray:
        """Twin minus log over `rows`, in shares of the median target (NaN: 0)."""
        self.evaluations += 1
        sim = replay_records(self.records, _candidate(self.base, values)).simulated[rows]
        return np.nan_to_num((sim - self.records.applied[rows]) / self.scale, nan=0.0)

    def solve(self, free, values: dict, rows: np.ndarray, preset_off: bool = False) -> _Solved:
        """Least squares over `free` from `values` (the others held), on `rows`."""
        from scipy.optimize import least_squares

        held = dict(values, **({name: 0.0 for name in PASS_START} if preset_off else {}))

        def fun(z):
            return self.residuals({**held, **_values(free, z)}, rows)

        x0 = np.array([_coord(p, held[p.name]) for p in free])
        lo = np.array([_coord(p, p.lo) for p in free])
        hi = np.array([_coord(p, p.hi) for p in free])
        x0 = np.clip(x0, lo, hi)
        step = np.array([0.05 if p.log else 0.02 * (p.hi - p.lo) for p in free])
        try:
            found = least_squares(fun, x0, bounds=(lo, hi), x_scale=(hi - lo) / 4, loss="soft_l1",
                                  f_scale=ROBUST_SCALE, diff_step=step / np.maximum(np.abs(x0), 1e-3),
                                  max_nfev=MAX_EVALUATIONS, xtol=1e-4, ftol=1e-6)
        except VrsimError:
            raise
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise ScenarioError(f"the fit failed: {exc}") from None
        std, why = _uncertainty(found, free)
        return _Solved({**held, **_values(free, found.x)}, std, why, bool(found.success), float(found.cost))

    def pass_start_grid(self, values: dict, rows: np.ndarray) -> dict:
        """The preset (speed, hold) of the least robust cost on `rows` over `PRESET_GRID`, then with it
        the opening transient (peak, time constant) over `OPENING_GRID`; the rest held."""
        speed = self.base.tractor.working_speed_m_s
        off = {"opening_peak_pct": 0.0, "opening_time_constant_s": 0.0}
        preset = {"startup_speed_m_s": [f * speed for f in PRESET_GRID[0]], "startup_hold_s": PRESET_GRID[1]}
        opening = {"opening_peak_pct": OPENING_GRID[0], "opening_time_constant_s": OPENING_GRID[1]}
        found = self.grid({**values, **off}, rows, preset)
        return {**found, **self.grid({**values, **found}, rows, opening)}

    def grid(self, values: dict, rows: np.ndarray, axes: dict, preset_off: bool = False) -> dict:
        """Of every combination of `axes` (name -> values tried), the one of the least robust cost on
        `rows`, the other parameters held at `values`."""
        held = dict(values, **({name: 0.0 for name in PASS_START} if preset_off else {}))
        names = list(axes)
        tried = [dict(zip(names, combo, strict=True)) for combo in itertools.product(*axes.values())]
        cost = [_robust_cost(self.residuals({**held, **t}, rows)) for t in tried]
        return tried[int(np.argmin(cost))]


def _values(free, z) -> dict:
    """The parameters at optimizer coordinates `z`, within their bounds (the finite differences may
    step a rounding past one)."""
    return {p.name: min(max(_value(p, v), p.lo), p.hi) for p, v in zip(free, z, strict=True)}


def _base(scenario: Scenario, records: MachineRecords) -> Scenario:
    """`scenario` with its controller's gains as numbers (the loop gain scales them)."""
    at_rest = dataclasses.replace(scenario, response=MachineResponse())
    plant = machine_plant(at_rest, _grid_for(scenario, records))
    cfg = resolved_controller(scenario.controller, plant, scenario.timing.control_period_s)
    return dataclasses.replace(scenario, controller=cfg)


def _grid_for(scenario: Scenario, records: MachineRecords):
    from vrsim.maps.units import convert_rate
    rate = convert_rate(records.target, records.unit or "kg/ha", "kg/ha", scenario.product.density_kg_l)
    return working_point_grid(records, rate)


def _candidate(base: Scenario, values: dict) -> Scenario:
    """The machine with fitted `values` (`FIT_PARAMS`' names; the loop gain scales the base's gains)."""
    values = dict(values)
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
    if p.name == "opening_time_constant_s":
        return 1.5
    return getattr(base.response, p.name)


def _robust_cost(r: np.ndarray) -> float:
    """least_squares' soft L1 cost at `ROBUST_SCALE`."""
    z = (r / ROBUST_SCALE) ** 2
    return float(np.sum(2 * (np.sqrt(1 + z) - 1)))


def _uncertainty(best, free) -> tuple[dict, dict]:
    """Standard deviations and the parameters not identified, from the optimum's Jacobian."""
    J, r = np.asarray(best.jac, float), np.asarray(best.fun, float)
    dof = max(1, r.size - len(free))
    s2 = float(r @ r) / dof
    cov = np.linalg.pinv(J.T @ J) * s2
    std, why = {}, {}
    for i, p in enumerate(free):
        value = _value(p, best.x[i])
        sd_z = math.sqrt(max(cov[i, i], 0.0))
        sd = value * sd_z if p.log else sd_z   # a log coordinate's spread, to first order
        span = (_coord(p, p.hi) - _coord(p, p.lo))
        std[p.name] = None
        if not np.any(J[:, i]):
            why[p.name] = "changing it moves no record's rate"
        elif sd_z > UNIDENTIFIABLE_SPREAD * span:
            why[p.name] = f"its standard deviation ({sd:.3g} {p.unit}) spans its range"
        else:
            std[p.name] = sd
    return std, why


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
    from vrsim.services.sim.machines.keys import implement_table
    from vrsim.services.sim.scenario_toml import toml_value

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
