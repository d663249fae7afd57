"""The simulation: scenarios, world building, the control core, landing, metrics, the in-process run.

Pure and importable (no Zenoh, no command line, no output files): this is vrsim's Python API, and
`__all__` lists its stable names::

    from vrsim.services.sim import load, run, with_changes, drive, control_and_account

Each name loads its module on first use (module ``__getattr__``), so importing one submodule, as
``vrsim run`` does to parse its options, stays as light as that submodule. Four names are also
names of submodules (`run`, `compare`, `evaluate`, `tune`): here they are the functions; the modules
are imported by their full names (``from vrsim.services.sim.run import drive``, `importlib.import_module`).
"""

import importlib
import sys
import types

# name -> the module that defines it.
_LAZY = {
    "Scenario": "vrsim.services.sim.scenario",
    "builtin_names": "vrsim.services.sim.scenario",
    "load": "vrsim.services.sim.scenario",
    "parse": "vrsim.services.sim.scenario",
    "with_changes": "vrsim.services.sim.scenario",
    "Drive": "vrsim.services.sim.run",
    "RunResult": "vrsim.services.sim.run",
    "control_and_account": "vrsim.services.sim.run",
    "drive": "vrsim.services.sim.run",
    "run": "vrsim.services.sim.run",
    "METRICS": "vrsim.services.sim.metrics",
    "MachineCheck": "vrsim.services.sim.limits",
    "machine_check": "vrsim.services.sim.limits",
    "ErrorPart": "vrsim.services.sim.error_split",
    "error_split": "vrsim.services.sim.error_split",
    "Comparison": "vrsim.services.sim.compare",
    "compare": "vrsim.services.sim.compare",
    "ControllerReport": "vrsim.services.sim.analyze",
    "analyze_controller": "vrsim.services.sim.analyze",
    "Sweep": "vrsim.services.sim.sweep",
    "load_sweep": "vrsim.services.sim.sweep",
    "parse_sweep": "vrsim.services.sim.sweep",
    "TuneParam": "vrsim.services.sim.tune",
    "TuneResult": "vrsim.services.sim.tune",
    "parse_param": "vrsim.services.sim.tune",
    "tune": "vrsim.services.sim.tune",
    "Evaluation": "vrsim.services.sim.evaluate",
    "evaluate": "vrsim.services.sim.evaluate",
}

__all__ = [*_LAZY]


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value  # resolved once
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


class _Package(types.ModuleType):
    """This package, whose API names win over its submodules of the same name."""

    def __setattr__(self, name: str, value) -> None:
        # Importing a submodule binds it as an attribute of its package: `services.sim.run` (the
        # module) would then hide `run` (the function) from ``from services.sim import run``.
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
