"""The registry of controller kinds: ``[controller] kind`` -> parameters dataclass and implementation.

A kind registers itself with the `register` decorator on its controller class::

    @register("aog_pi", AogPiParams, "AgOpenGPS RateController's normalised PI")
    class AogPi(Controller): ...

A kind may also bring its own loop (``loop=``): the linear PID's lifted-matrix fast path, or the
`ideal` meter, which has no plant at all. `controller.factory` looks kinds up here; nothing else
branches on the kind's name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from common import ControllerError


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
    """

    name: str
    params: type | None
    controller: Callable | None
    summary: str
    loop: Callable | None = None


KINDS: dict[str, Kind] = {}


def register(name: str, params: type | None, summary: str, loop: Callable | None = None):
    """Class decorator: register the decorated controller class (or None-returning factory) as `name`."""
    def decorate(impl):
        if name in KINDS:
            raise ValueError(f"controller kind {name!r} is registered twice")
        KINDS[name] = Kind(name=name, params=params, controller=impl, summary=summary, loop=loop)
        return impl
    return decorate


def get(name: str) -> Kind:
    """The kind `name`; `ControllerError` listing the known kinds otherwise."""
    try:
        return KINDS[name]
    except (KeyError, TypeError):
        raise ControllerError(f"controller kind must be one of {', '.join(KINDS)}, got {name!r}") from None
