"""The registry of controller kinds: ``[controller] kind`` -> parameters dataclass and implementation.

A kind registers itself with the `register` decorator on its controller class::

    @register("aog_pi", AogPiParams, "AgOpenGPS RateController's normalised PI")
    class AogPi(Controller): ...

A kind may also bring its own loop (``loop=``): the linear PID's lifted-matrix fast path; the
`ideal` meter, which has no plant at all, is only a loop (`register_loop`). `controller.factory`
looks kinds up here to build them; a new kind needs no change anywhere else (only the PID family's
flat keys and the ``python`` kind's file and class are known to `ControllerConfig` by name).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from vrsim.common import ControllerError


@dataclass(frozen=True)
class Kind:
    """One registered controller kind.

    Attributes
    ----------
    name : str
        The ``[controller] kind`` value.
    params : type or None
        Its `controller.params.KindParams` subclass (None: the parameters are passed through as a dict).
    controller : callable or None
        ``controller(params, loop_info, n)`` -> a `controller.Controller`; None if the kind only has a
        loop.
    summary : str
        One line: what it is and where it comes from.
    loop : callable or None
        ``loop(params, loop_info, n, record_fine)`` -> a loop object (`PlantLoop`'s interface) or None
        to use `PlantLoop` around `controller`.
    batch : callable or None
        ``batch(params_list, loop_info)`` -> ``[(indices, loop), ...]``: loops that run several
        parameter sets of this kind at once, one loop per parameter set (the PID's fast path with
        gains per loop); every index of `params_list` in exactly one of them. None: one loop each.
    """

    name: str
    params: type | None
    controller: Callable | None
    summary: str
    loop: Callable | None = None
    batch: Callable | None = None


KINDS: dict[str, Kind] = {}


def register(name: str, params: type | None, summary: str, loop: Callable | None = None,
             batch: Callable | None = None):
    """Class decorator: register the decorated controller class as kind `name` (see `Kind`)."""
    def decorate(impl):
        _add(Kind(name=name, params=params, controller=impl, summary=summary, loop=loop, batch=batch))
        return impl
    return decorate


def register_loop(name: str, params: type | None, summary: str, loop: Callable) -> None:
    """Register kind `name` that is a loop of its own, with no controller (the `ideal` meter)."""
    _add(Kind(name=name, params=params, controller=None, summary=summary, loop=loop))


def _add(kind: Kind) -> None:
    if kind.name in KINDS:
        raise ValueError(f"controller kind {kind.name!r} is registered twice")
    KINDS[kind.name] = kind


def get(name: str) -> Kind:
    """The kind `name`; `ControllerError` listing the known kinds otherwise."""
    try:
        return KINDS[name]
    except (KeyError, TypeError):
        raise ControllerError(f"controller kind must be one of {', '.join(KINDS)}, got {name!r}") from None
