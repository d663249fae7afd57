"""Kind ``python``: a controller class written by the user, loaded from a Python file.

``[controller] kind = "python"``, ``file = "my_controller.py"`` (relative to the scenario's folder),
``class = "MyController"``, ``params = {...}``. The class follows `controller.interface`
(``__init__(params, loop, n)``, ``step``, ``reset``, ``state``, ``set_state``); ``params`` reaches
its constructor as a dict, unchecked. It runs in the same `PlantLoop` as the built-in kinds; a
``step(target_rpm, measured_rpm, context)`` gets the `controller.context.ControlContext` each
period, a two-argument ``step`` does not (decided once, when the class is loaded).

Errors name the user's file and line:

* a file that cannot be loaded, a missing or incomplete class, or a constructor that rejects its
  params (raising `ControllerError`, ValueError, TypeError or KeyError) -> `ControllerError`
  (bad input: the CLI's exit 2);
* anything else raised inside the user's code -> `UserCodeError` (a crash: the CLI's exit 1), which
  carries ``file``, ``line`` and the traceback of the user's frames.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import inspect
import os
import sys
import traceback
from dataclasses import dataclass, field

from vrsim.common import ControllerError, files
from vrsim.controller.context import takes_context
from vrsim.controller.interface import LoopInfo, check_controller_class
from vrsim.controller.params import KindParams, param
from vrsim.controller.plant_loop import as_loop_currents
from vrsim.controller.registry import register

BAD_PARAMS = (ControllerError, ValueError, TypeError, KeyError)


class UserCodeError(RuntimeError):
    """A user-defined controller crashed. Not bad input (not a `VrsimError`): a bug in user code.

    Attributes
    ----------
    file : str
        The user's file.
    line : int
        The line in it where the exception was raised (the innermost frame in that file).
    user_traceback : str
        The traceback, formatted (for ``VRSIM_DEBUG=1``).
    """

    def __init__(self, message: str, file: str, line: int, user_traceback: str = ""):
        super().__init__(message)
        self.file = file
        self.line = line
        self.user_traceback = user_traceback


def _line_in(exc: BaseException, path: str, fallback: int) -> int:
    """Line of the innermost traceback frame in `path`, or `fallback`."""
    if isinstance(exc, SyntaxError) and exc.filename and os.path.abspath(exc.filename) == path:
        return exc.lineno or fallback
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if os.path.abspath(f.filename) == path]
    return frames[-1].lineno if frames else fallback


MAX_SOURCE_BYTES = 1024 * 1024  # a controller's source file: a few kB; read whole by `check_defines_class`


def check_defines_class(path: str, class_name: str) -> None:
    """Refuse, without running any of it, a Python file that does not bind ``class_name`` at its top
    level (a ``class``, an assignment or an import, perhaps under a top-level ``if`` or ``try``).

    Importing a file runs its module-level code before its class can be looked at; a service that
    loads a file a scenario from the bus names reads it as text first (a regular file of at most
    `MAX_SOURCE_BYTES`, parsed by `ast`), so a file that holds no such class never runs.

    Raises
    ------
    ControllerError
        Naming the file (and line, for a syntax error) and the class.
    """
    data = files.read_bytes(path, None, ControllerError, limit=MAX_SOURCE_BYTES)
    try:
        tree = ast.parse(data, filename=path)
    except SyntaxError as exc:
        raise ControllerError(f"controller file {path}:{exc.lineno or 1}: cannot be loaded: "
                              f"SyntaxError: {exc.msg}") from None
    except (ValueError, RecursionError, MemoryError) as exc:  # null bytes; nesting the parser refuses
        raise ControllerError(f"controller file {path}: cannot be loaded: {type(exc).__name__}") from None
    if class_name not in _top_level_names(tree.body):
        raise ControllerError(f"controller file {path}: no class {class_name!r} at its top level "
                              "(refused before running it)")


_BLOCKS = (ast.If, ast.Try, getattr(ast, "TryStar", ast.Try), ast.With, ast.ExceptHandler)


def _top_level_names(body: list) -> set[str]:
    """Names a module's statements bind when it is imported: classes, functions, assignments and
    imports, looking into top-level ``if``/``try``/``with`` blocks but not into functions or classes."""
    names: set[str] = set()
    for node in body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
        for block in ("body", "orelse", "finalbody", "handlers"):
            if isinstance(node, _BLOCKS) and hasattr(node, block):
                names |= _top_level_names(getattr(node, block))
    return names


def _load_user_class(path: str, class_name: str):
    """Load class `class_name` from the Python file `path` (absolute) and check it is a controller.

    Raises `ControllerError` naming the file (and line) when the file is missing, does not load, or
    has no such class or not the interface's methods.
    """
    if not os.path.isabs(path):
        raise ControllerError(f"controller file must be an absolute path by now, got {path!r}")
    if not os.path.isfile(path):
        raise ControllerError(f"controller file {path}: no such file")
    digest = hashlib.sha1(path.encode()).hexdigest()[:12]
    name = f"vrsim_user_{digest}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module   # dataclasses and pickling look classes up by module name
    try:
        spec.loader.exec_module(module)
    except BaseException as exc:
        del sys.modules[name]
        if not isinstance(exc, Exception):
            raise
        raise ControllerError(f"controller file {path}:{_line_in(exc, path, 1)}: cannot be loaded: "
                              f"{type(exc).__name__}: {exc}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        found = sorted(k for k, v in vars(module).items() if inspect.isclass(v) and v.__module__ == name)
        raise ControllerError(f"controller file {path}: no class {class_name!r} "
                              f"(classes in it: {', '.join(found) or 'none'})")
    check_controller_class(cls, f"controller file {path}: class {class_name}")
    return cls


@dataclass(frozen=True)
class PythonParams(KindParams):
    """Parameters of the ``python`` kind (from ``[controller]`` ``file``, ``class``, ``params``).

    Parameters
    ----------
    file : str
        Absolute path of the user's Python file.
    class_name : str
        The controller class in it.
    params : dict
        Passed to the class's constructor as it is.
    """

    KIND = "python"
    file: str = param("")
    class_name: str = param("")
    params: dict = field(default_factory=dict)


@register("python", PythonParams, "a user's controller class from a Python file (docs/controllers.md)")
class UserController:
    """Runs a user's controller class; turns its exceptions into errors that name its file and line."""

    def __init__(self, params: PythonParams, loop: LoopInfo, n: int):
        cls = _load_user_class(params.file, params.class_name)
        self.file = params.file
        self.name = f"{os.path.basename(params.file)}:{params.class_name}"
        self._class_line = inspect.getsourcelines(cls)[1]
        try:
            self.impl = cls(dict(params.params), loop, n)
        except BAD_PARAMS as exc:
            line = _line_in(exc, self.file, self._class_line)
            raise ControllerError(f"controller file {self.file}:{line}: "
                                  f"{params.class_name} rejected its params {params.params!r}: "
                                  f"{type(exc).__name__}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a crash in user code, reported with its line
            raise self._crash(exc, "__init__") from exc
        self._step = self.impl.step
        # the wrapper's step has the user's arity, so that `PlantLoop` sees whether it takes the context
        self.step = self._step_with_context if takes_context(self._step) else self._step_plain

    def _crash(self, exc: Exception, method: str) -> UserCodeError:
        line = _line_in(exc, self.file, self._class_line)
        cls = type(self.impl).__name__ if hasattr(self, "impl") else self.name.split(":")[1]
        return UserCodeError(f"{self.file}:{line}: {cls}.{method} raised {type(exc).__name__}: {exc}",
                             self.file, line, "".join(traceback.format_exception(exc)))

    def _step_plain(self, target_rpm, measured_rpm):
        try:
            current = self._step(target_rpm, measured_rpm)
        except Exception as exc:  # noqa: BLE001
            raise self._crash(exc, "step") from exc
        return as_loop_currents(current, len(target_rpm), self)

    def _step_with_context(self, target_rpm, measured_rpm, context):
        try:
            current = self._step(target_rpm, measured_rpm, context)
        except Exception as exc:  # noqa: BLE001
            raise self._crash(exc, "step") from exc
        return as_loop_currents(current, len(target_rpm), self)

    def reset(self):
        try:
            self.impl.reset()
        except Exception as exc:  # noqa: BLE001
            raise self._crash(exc, "reset") from exc

    def state(self):
        try:
            return self.impl.state()
        except Exception as exc:  # noqa: BLE001
            raise self._crash(exc, "state") from exc

    def set_state(self, state):
        try:
            self.impl.set_state(state)
        except Exception as exc:  # noqa: BLE001
            raise self._crash(exc, "set_state") from exc
