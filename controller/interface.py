"""The controller interface: what every rate controller in vrsim is, built in or written by a user.

A controller runs n independent loops at once. Once per control period T it gets, for each loop,
the target metering-shaft speed and the speed sensor's (delayed) reading, both in rpm and as arrays
of shape (n,), and returns the valve current to hold over the next period [A], shape (n,)::

    current_a = controller.step(target_rpm, measured_rpm)

A controller whose ``step`` takes a third argument gets, besides, the period's context (ground speed,
prescribed rate, sections on, time, the plant's nominal gain: `controller.context.ControlContext`)::

    current_a = controller.step(target_rpm, measured_rpm, context)

The loop reads the step's arity once, when it is built; a two-argument ``step`` is called as above.

The loop around it (`controller.PlantLoop`) clips the targets to ``[0, shaft_rpm_max]`` before the
call and the returned current to ``[current_min_a, current_max_a]`` after it, then advances the
plant by one period. A controller that needs to know what was really applied (anti-windup) clips
itself with the limits in `LoopInfo`.

``reset()`` returns to rest; ``state()`` returns everything the controller remembers as plain data
(a dict of floats, ints, bools, strings, numpy arrays or nested dicts of them) and
``set_state(state)`` restores it, also after a JSON round trip has turned the arrays into lists.
After ``set_state(s)`` the controller must continue exactly as the one ``s`` was taken from (the
Zenoh controller service carries state across batches this way). Nothing else may persist between
calls: no clock, no randomness without its seed in the state.

Subclassing `Controller` is optional: a class with these four methods and a constructor
``__init__(self, params, loop: LoopInfo, n: int)`` is a controller (`check_controller_class`).

Optional, for speed: with n = 1 a controller may also offer ``step_one(target_rpm: float,
measured_rpm: float) -> float``; `PlantLoop` then calls it instead of `step` (the built-in kinds do,
through `LawController`, and spare about a microsecond per numpy call on one-element arrays).
"""

from __future__ import annotations

import abc
import inspect
from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller import ops
from vrsim.controller.plant import PlantParams

METHODS = ("step", "reset", "state", "set_state")


@dataclass(frozen=True)
class LoopInfo:
    """What a controller may know about the loop it runs in.

    Attributes
    ----------
    plant : PlantParams
        The plant model (model-based controllers use it; a controller of a real machine would not
        know it exactly, see `ff_pi`'s valve calibration).
    control_period_s : float
        T, the period between calls of `step` [s].
    plant_step_s : float
        The plant's fine simulation step [s] (only for controllers that simulate a model).
    """

    plant: PlantParams
    control_period_s: float = 0.05
    plant_step_s: float = 0.001

    @property
    def current_min_a(self) -> float:
        """Lowest valve current the loop applies [A]."""
        return self.plant.current_min_a

    @property
    def current_max_a(self) -> float:
        """Highest valve current the loop applies [A]."""
        return self.plant.current_max_a

    @property
    def shaft_rpm_max(self) -> float:
        """Highest target the loop passes on [rpm]."""
        return self.plant.shaft_rpm_max

    @property
    def sensor_gain_v_per_rpm(self) -> float:
        """Ks: sensor volts per shaft rpm (PID gains act on volts, as in the paper)."""
        return self.plant.sensor_gain_v_per_rpm

    @property
    def amplifier_gain_a_per_v(self) -> float:
        """Ka: valve amperes per controller volt."""
        return self.plant.amplifier_gain_a_per_v


class Controller(abc.ABC):
    """Base class of the built-in controllers (see the module docstring for the contract).

    Parameters
    ----------
    params
        The kind's parameter dataclass (a dict for user-defined controllers).
    loop : LoopInfo
    n : int
        Number of loops.
    """

    def __init__(self, params, loop: LoopInfo, n: int):
        self.params = params
        self.loop = loop
        self.n = n

    @abc.abstractmethod
    def step(self, target_rpm: np.ndarray, measured_rpm: np.ndarray) -> np.ndarray:
        """Valve current for the next period [A], shape (n,), from targets and readings [rpm], (n,).

        A subclass may take a third argument, ``context`` (`controller.context.ControlContext`), to be
        given the period's ground speed, rate, sections, time and plant gain."""

    @abc.abstractmethod
    def reset(self) -> None:
        """Forget everything: back to rest."""

    @abc.abstractmethod
    def state(self) -> dict:
        """Everything the controller remembers, as plain data (see the module docstring)."""

    @abc.abstractmethod
    def set_state(self, state: dict) -> None:
        """Restore what `state` returned (arrays may come back as lists)."""

    def clip_current(self, current_a: np.ndarray) -> np.ndarray:
        """The current the loop will really apply: `current_a` within the valve's limits [A]."""
        return np.minimum(np.maximum(current_a, self.loop.current_min_a), self.loop.current_max_a)


class LawController(Controller):
    """Base of the built-in kinds: the control law written once (`law`) for one loop's floats and for n
    loops' arrays (`controller.ops`), memory kept as floats when n = 1.

    `step` (arrays, the interface) and `step_one` (floats, what `PlantLoop` calls for one loop) both
    run `law`; subclasses implement `law` and `reset`. A kind whose memory is one value per loop in
    each attribute named in `MEMORY` gets `state`/`set_state` from here; others override them.
    """

    MEMORY: tuple[str, ...] = ()

    def state(self) -> dict:
        return {k: ops.as_array(getattr(self, k), self.n) for k in self.MEMORY}

    def set_state(self, state: dict) -> None:
        got = state_arrays(state, {k: (self.n,) for k in self.MEMORY}, self.params.KIND)
        for k in self.MEMORY:
            setattr(self, k, ops.from_array(got[k], self.n))

    @abc.abstractmethod
    def law(self, target_rpm, measured_rpm):
        """Valve current [A] from target and reading [rpm]: floats when n = 1, else arrays (n,)."""

    def step(self, target_rpm: np.ndarray, measured_rpm: np.ndarray) -> np.ndarray:
        if self.n == 1:
            return np.array((self.law(float(target_rpm[0]), float(measured_rpm[0])),))
        return self.law(np.asarray(target_rpm, dtype=float), np.asarray(measured_rpm, dtype=float))

    def step_one(self, target_rpm: float, measured_rpm: float) -> float:
        """`step` for one loop with floats (n = 1 only)."""
        return self.law(target_rpm, measured_rpm)


def state_arrays(state: dict, shapes: dict[str, tuple], owner: str) -> dict[str, np.ndarray]:
    """The arrays `shapes` names, taken from `state` as float arrays of the given shapes.

    Raises `ControllerError` naming `owner` and the key when one is missing or has another shape.
    """
    if not isinstance(state, dict):
        raise ControllerError(f"{owner} state must be a dict, got {type(state).__name__}")
    out = {}
    for key, shape in shapes.items():
        if key not in state:
            raise ControllerError(f"{owner} state has no {key!r} (has {', '.join(map(repr, state))})")
        try:
            value = np.array(state[key], dtype=float)
        except (TypeError, ValueError):
            raise ControllerError(f"{owner} state {key!r} must be numbers, got {state[key]!r}") from None
        if value.shape != shape:
            raise ControllerError(f"{owner} state {key!r} must have shape {shape}, got {value.shape}")
        out[key] = value
    return out


def check_controller_class(cls, where: str) -> None:
    """Raise `ControllerError` naming `where` unless `cls` is a class with the interface's methods and
    a constructor taking ``(params, loop, n)``."""
    if not inspect.isclass(cls):
        raise ControllerError(f"{where} is not a class, got {type(cls).__name__}")
    for name in METHODS:
        if not callable(getattr(cls, name, None)):
            raise ControllerError(f"{where} has no method {name}() (a controller needs "
                                  f"{', '.join(METHODS)})")
    try:
        inspect.signature(cls).bind(None, None, None)
    except TypeError:
        raise ControllerError(f"{where}.__init__ must take (params, loop, n), "
                              f"has {inspect.signature(cls)}") from None
    except ValueError:
        pass   # no signature to inspect (a builtin base): let construction tell
