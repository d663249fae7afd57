"""Build controllers and loops from a `ControllerConfig`: the one place that turns configuration into
running objects (it sits above `tuning`, so the gain sources never import the loops that use them).

``build_loop(plant, cfg)`` is what a run drives: the kind's own loop if it has one (the linear PID's
lifted-matrix fast path, the `ideal` meter), else `PlantLoop` around ``build_controller(...)``.
"""

from __future__ import annotations

from vrsim.common import ControllerError
from vrsim.controller import kinds as _kinds  # noqa: F401 - registers the built-in kinds
from vrsim.controller import registry
from vrsim.controller.config import ControllerConfig
from vrsim.controller.gains import PidGains
from vrsim.controller.interface import LoopInfo
from vrsim.controller.plant import PlantParams
from vrsim.controller.plant_loop import PlantLoop


def loop_info(plant: PlantParams, control_period_s: float = 0.05, plant_step_s: float = 0.001) -> LoopInfo:
    """The `LoopInfo` of `plant` at period `control_period_s` and plant step `plant_step_s` [s]."""
    if not isinstance(plant, PlantParams):
        raise ControllerError(f"plant must be PlantParams, got {type(plant).__name__}")
    return LoopInfo(plant=plant, control_period_s=float(control_period_s), plant_step_s=float(plant_step_s))


def _config(cfg) -> ControllerConfig:
    if not isinstance(cfg, ControllerConfig):
        raise ControllerError(f"cfg must be ControllerConfig, got {type(cfg).__name__}")
    return cfg


def build_controller(cfg: ControllerConfig, plant: PlantParams, control_period_s: float = 0.05,
                     plant_step_s: float = 0.001, n: int = 1):
    """The controller `cfg` asks for, for `n` loops of `plant` (an object with the controller interface).

    Raises `ControllerError` for a kind that is a loop, not a controller (``ideal``).
    """
    cfg = _config(cfg)
    kind = registry.get(cfg.registry_kind)
    if kind.controller is None:
        raise ControllerError(f"controller kind {kind.name!r} has no controller: it is a loop of its own "
                              f"(use build_loop)")
    return kind.controller(cfg.kind_params(), loop_info(plant, control_period_s, plant_step_s), n)


def build_loop(plant: PlantParams, cfg: ControllerConfig, control_period_s: float = 0.05,
               plant_step_s: float = 0.001, n: int = 1, record_fine: bool = False, fast: bool = True):
    """`n` loops of `plant` under the controller `cfg`, advanced one control period per ``step``.

    Parameters
    ----------
    plant : PlantParams
    cfg : ControllerConfig
    control_period_s : float
        Controller period T [s] (the paper: 0.05).
    plant_step_s : float
        Plant discretization step h [s] (the paper's bench: 0.001); T must be a multiple of h.
    n : int
        Number of identical loops (e.g. one per section).
    record_fine : bool
        Allow ``step_fine`` (the shaft speed at every plant step).
    fast : bool
        Use the kind's own loop when it has one (the PID's lifted-matrix fast path); False runs the
        PID through the controller interface and `PlantLoop` instead (same numbers, slower).

    Returns
    -------
    ClosedLoop, PlantLoop or IdealLoop
        All with ``step``, ``run``, ``step_fine``, ``reset``, ``state``/``set_state``, ``n``.
    """
    cfg = _config(cfg)
    info = loop_info(plant, control_period_s, plant_step_s)
    kind = registry.get(cfg.registry_kind)
    params = cfg.kind_params()
    if kind.loop is not None and (fast or kind.controller is None):
        return kind.loop(params, info, n, record_fine)
    return PlantLoop(info, kind.controller(params, info, n), n=n, record_fine=record_fine)


def build_variant_loops(plant: PlantParams, cfgs, control_period_s: float = 0.05,
                        plant_step_s: float = 0.001) -> list[tuple[list[int], object]]:
    """Loops for the controllers `cfgs` (one loop each, on the same targets), batched where their kind
    can: ``[(indices into cfgs, loop of len(indices) loops), ...]``, every index once.

    A kind with a ``batch`` (the PID family: one lifted-matrix loop with gains per loop for each
    form) runs its parameter sets together; every other configuration gets its own one-loop
    `build_loop`. Loop i of a batch gives the same numbers as `build_loop` of cfg i to rounding.
    """
    info = loop_info(plant, control_period_s, plant_step_s)
    by_kind: dict[str, list[int]] = {}
    for i, cfg in enumerate(cfgs):
        by_kind.setdefault(_config(cfg).registry_kind, []).append(i)
    out = []
    for name, idx in by_kind.items():
        kind = registry.get(name)
        if kind.batch is None:
            out += [([i], build_loop(plant, cfgs[i], control_period_s, plant_step_s)) for i in idx]
        else:
            out += [([idx[j] for j in part], loop)
                    for part, loop in kind.batch([cfgs[i].kind_params() for i in idx], info)]
    return out


def resolve_gains(cfg: ControllerConfig, plant: PlantParams | None = None,
                  control_period_s: float = 0.05) -> PidGains:
    """The PID gains of a P/PI/PID configuration (``gains="relay"`` runs the relay experiment on `plant`)."""
    params = _config(cfg).kind_params()
    if cfg.registry_kind != "pid":
        raise ControllerError(f"controller kind {cfg.kind!r} has no PID gains to resolve")
    return params.resolve(plant, control_period_s)
