"""Batch simulation: N independent loops (different gains, plants or setpoints) advance together.

A batch of N gives the same numbers as N single runs: each loop's row of the state only ever meets its
own row of the matrices (tests check it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.config import ControllerConfig
from vrsim.controller.factory import build_loop, resolve_gains
from vrsim.controller.gains import PidGains
from vrsim.controller.loop import ClosedLoop
from vrsim.controller.plant import PlantParams


@dataclass(frozen=True)
class SimResult:
    """Trajectories of a batch of n loops over K control periods of N plant steps each.

    Attributes
    ----------
    t_s : ndarray, shape (K N + 1,), or None
        Plant-step times from 0 [s] (None unless run with ``fine=True``).
    shaft_rpm : ndarray, shape (n, K N + 1), or None
        Metering-shaft speed at every plant step, starting at rest [rpm].
    tick_t_s : ndarray, shape (K,)
        Start time of each control period [s].
    current_a, measured_rpm, shaft_rev, target_rpm : ndarray, shape (K, n)
        Per period: valve current, sensor reading used, shaft revolutions, clipped target.
    """

    t_s: np.ndarray
    shaft_rpm: np.ndarray
    tick_t_s: np.ndarray
    current_a: np.ndarray
    measured_rpm: np.ndarray
    shaft_rev: np.ndarray
    target_rpm: np.ndarray


def _gains_for(controllers, plants, n, control_period_s):
    """(list of n PidGains, form, derivative_on_measurement) from configs or gains."""
    items = list(controllers) if isinstance(controllers, Sequence) else [controllers] * n
    if len(items) != n:
        raise ControllerError(f"controllers must be one or {n} items (n={n}), got {len(items)}")
    plant_list = list(plants) if isinstance(plants, Sequence) else [plants] * n
    if all(isinstance(c, PidGains) for c in items):
        return items, None, None
    if not all(isinstance(c, ControllerConfig) and c.registry_kind == "pid" for c in items):
        raise ControllerError("a batch of controllers must be PidGains or P/PI/PID ControllerConfig items "
                              "(other kinds: one ControllerConfig for all n loops)")
    forms = {(c.form, c.derivative_on_measurement) for c in items}
    if len(forms) != 1:
        raise ControllerError(f"one batch needs one form and derivative_on_measurement, got {sorted(forms)}")
    cache = {}
    gains = []
    for c, p in zip(items, plant_list, strict=True):
        key = (c, p if c.gains == "relay" else None)
        if key not in cache:
            cache[key] = resolve_gains(c, p, control_period_s)
        gains.append(cache[key])
    form, dom = forms.pop()
    return gains, form, dom


def simulate(plants, controllers, setpoint_rpm, duration_s: float, control_period_s: float = 0.05,
             plant_step_s: float = 0.001, n: int | None = None, form: str = "incremental",
             derivative_on_measurement: bool = False, load_torque_nm=0.0,
             fine: bool = True) -> SimResult:
    """Simulate n loops from rest.

    Parameters
    ----------
    plants : PlantParams or sequence of n
    controllers : ControllerConfig, PidGains, or a sequence of n of either
        With PidGains, `form` and `derivative_on_measurement` apply; configs carry their own. A
        sequence must be PID gains or P/PI/PID configs (one lifted matrix); any other kind runs as one
        ControllerConfig for all n loops, on one plant.
    setpoint_rpm : float, ndarray (n,) or ndarray (K, n)
        Shaft-speed setpoint [rpm]: constant, per loop, or per control period and loop.
    duration_s : float
        Simulated time [s]; rounded up to whole control periods K.
    n : int, optional
        Batch size; by default the length of whichever argument is a sequence or array, else 1.
    fine : bool
        Record the shaft speed at every plant step (memory n * duration / plant_step_s floats);
        without it `t_s` and `shaft_rpm` are None and only per-period records are kept.
    """
    sizes = {len(a) for a in (plants, controllers) if isinstance(a, Sequence)}
    sp = np.asarray(setpoint_rpm, dtype=float)
    if sp.ndim >= 1:
        sizes.add(sp.shape[-1])
    if n is None:
        n = sizes.pop() if len(sizes) == 1 else (1 if not sizes else -1)
    if n < 1 or len(sizes) > 1:
        raise ControllerError(f"plants, controllers and setpoint_rpm disagree on the batch size: {sizes}")
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ControllerError(f"duration_s must be a positive number, got {duration_s!r}")
    if isinstance(controllers, ControllerConfig) and controllers.registry_kind != "pid":
        if not isinstance(plants, PlantParams):
            raise ControllerError(f"kind {controllers.kind!r} runs its n loops on one plant, got {plants!r}")
        loop = build_loop(plants, controllers, control_period_s, plant_step_s, n, record_fine=fine)
    else:
        gains, cfg_form, cfg_dom = _gains_for(controllers, plants, n, control_period_s)
        loop = ClosedLoop(plants, gains, form=cfg_form or form,
                          derivative_on_measurement=derivative_on_measurement if cfg_dom is None else cfg_dom,
                          control_period_s=control_period_s, plant_step_s=plant_step_s, n=n,
                          record_fine=fine)
    K = int(np.ceil(duration_s / control_period_s - 1e-9))
    if sp.ndim == 2 and sp.shape[0] < K:
        raise ControllerError(f"setpoint_rpm has {sp.shape[0]} rows, the run needs {K} control periods")
    targets = sp[:K] if sp.ndim == 2 else np.broadcast_to(sp, (K, n))
    N = loop.n_fine
    rmax = (np.array([p.shaft_rpm_max for p in plants]) if isinstance(plants, Sequence)
            else plants.shaft_rpm_max)
    rec = {"target_rpm": np.clip(targets, 0.0, rmax)}
    if fine:
        shaft = np.zeros((n, K * N + 1))
        for name in ("current_a", "measured_rpm", "shaft_rev"):
            rec[name] = np.empty((K, n))
        for k in range(K):
            out, f = loop.step_fine(targets[k], load_torque_nm)
            shaft[:, 1 + k * N:1 + (k + 1) * N] = f
            rec["current_a"][k] = out.current_a
            rec["measured_rpm"][k] = out.measured_rpm
            rec["shaft_rev"][k] = out.shaft_rev
        t = np.arange(K * N + 1) * plant_step_s
    else:
        out = loop.run(targets, load_torque_nm)
        rec.update(current_a=out.current_a, measured_rpm=out.measured_rpm, shaft_rev=out.shaft_rev)
        shaft = t = None
    rec["shaft_rpm"] = shaft
    return SimResult(t_s=t, tick_t_s=np.arange(K) * control_period_s, **rec)
