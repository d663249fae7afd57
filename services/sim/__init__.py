"""The simulation: scenarios, world building, the control core, landing, metrics, the in-process run.

Pure and importable (no Zenoh, no command line, no output files): this is vrsim's Python API, and
`__all__` lists its stable names::

    from services.sim import load, run, with_changes, drive, control_and_account

Each name loads its module on first use (module ``__getattr__``), so importing one submodule, as
``vrsim run`` does to parse its options, stays as light as that submodule. Four names are also
names of submodules (`run`, `compare`, `evaluate`, `tune`): here they are the functions; the modules
are imported by their full names (``from services.sim.run import drive``, `importlib.import_module`).
"""

import importlib
import sys
import types

# name -> the module that defines it.
_LAZY = {
    "Scenario": "services.sim.scenario",
    "builtin_names": "services.sim.scenario",
    "load": "services.sim.scenario",
    "parse": "services.sim.scenario",
    "with_changes": "services.sim.scenario",
    "Drive": "services.sim.run",
    "RunResult": "services.sim.run",
    "control_and_account": "services.sim.run",
    "drive": "services.sim.run",
    "run": "services.sim.run",
    "METRICS": "services.sim.metrics",
    "MachineCheck": "services.sim.limits",
    "machine_check": "services.sim.limits",
    "ErrorPart": "services.sim.error_split",
    "error_split": "services.sim.error_split",
    "Comparison": "services.sim.compare",
    "compare": "services.sim.compare",
    "ControllerReport": "services.sim.analyze",
    "analyze_controller": "services.sim.analyze",
    "Sweep": "services.sim.sweep",
    "load_sweep": "services.sim.sweep",
    "parse_sweep": "services.sim.sweep",
    "TuneParam": "services.sim.tune",
    "TuneResult": "services.sim.tune",
    "parse_param": "services.sim.tune",
    "tune": "services.sim.tune",
    "Evaluation": "services.sim.evaluate",
    "evaluate": "services.sim.evaluate",
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
