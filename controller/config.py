"""`ControllerConfig`: the ``[controller]`` table of a scenario, checked when it is made.

Two shapes, one dataclass:

* the paper's PID family, as scenarios have always written it: ``kind = "P" | "PI" | "PID"`` (or
  ``"pid"``, the same as ``"PID"``) with `form`, `gains`, `kp`, `ki`, `kd`,
  `derivative_on_measurement` directly in the table;
* every other registered kind: ``kind = "aog_pi"`` etc. with its parameters in ``params = {...}``,
  checked by that kind's dataclass (unknown keys and bad values name the kind, key and value). The
  kind ``python`` (a user's controller) also takes ``file`` and ``class`` (`class_name` here; the
  TOML key ``class`` is a Python keyword, `from_table` renames it) and passes `params` to the user's
  class unchecked.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace

from vrsim.common import ControllerError, in_range
from vrsim.controller import registry
from vrsim.controller.gains import TERMS

PID_KINDS = {"P": "P", "PI": "PI", "PID": "PID", "pid": "PID"}    # config kind -> terms of kind pid
PID_KEYS = ("form", "gains", "kp", "ki", "kd", "derivative_on_measurement")
PID_DEFAULTS = {"form": "incremental", "gains": "paper", "derivative_on_measurement": False}
USER_KIND = "python"
LOOK_AHEAD_AUTO = "auto"
LOOK_AHEAD_MAX_S = 30.0     # a look-ahead beyond this is a typo, not a machine


@dataclass(frozen=True)
class ControllerConfig:
    """Which controller runs the valve, and its parameters.

    Parameters
    ----------
    kind : str
        "P", "PI", "PID" (the paper's PID family, kind ``pid``; "pid" = "PID"), or a registered kind:
        "aog_pi", "ff_pi", "smith", "fuzzy_pid", "ideal", "python" (`controller.registry.KINDS`).
    form, gains, kp, ki, kd, derivative_on_measurement
        The PID family's parameters (see `controller.kinds.pid.PidParams`); only with kind P, PI, PID.
    params : dict
        Parameters of any other kind (see its params dataclass and ``docs/controllers.md``).
    file, class_name : str or None
        Kind "python" only: the user's Python file (an absolute path by the time a loop is built; see
        `resolved`) and the controller class in it.
    look_ahead_s : float, "auto" or None
        How far ahead in time the rate is looked up [s] (any kind; used by the field run, not by the
        loop): None (default) the implement's delivery delay, as before this key existed; a number of
        seconds; or "auto": the delivery delay plus this loop's measured mean lag
        (`controller.response.response_time`). See ``docs/controllers.md``, "Look-ahead".
    look_ahead_tune : float
        Auto-tune gain in [0, 1]: after each clean rate step the look-ahead moves by this fraction of
        the step's measured early/late error (0, the default: fixed look-ahead).
    """

    kind: str = "PID"
    form: str | None = None
    gains: str | None = None
    kp: float | None = None
    ki: float | None = None
    kd: float | None = None
    derivative_on_measurement: bool | None = None
    params: dict = field(default_factory=dict, hash=False)
    file: str | None = None
    class_name: str | None = None
    look_ahead_s: float | str | None = None
    look_ahead_tune: float = 0.0

    def __post_init__(self):
        if not isinstance(self.kind, str) or (self.kind not in PID_KINDS and self.kind not in registry.KINDS):
            known = [*TERMS, *(k for k in registry.KINDS if k != "pid")]
            raise ControllerError(f"controller kind must be one of {', '.join(known)}, got {self.kind!r}")
        if not isinstance(self.params, dict):
            raise ControllerError(f"controller params must be a table, got {self.params!r}")
        if self.kind in PID_KINDS:
            for key, default in PID_DEFAULTS.items():
                if getattr(self, key) is None:
                    object.__setattr__(self, key, default)
            self._only_for("params", bool(self.params), "is for kinds other than P, PI, PID")
        else:
            for key in PID_KEYS:
                self._only_for(key, getattr(self, key) is not None,
                               "is a key of kinds P, PI, PID; put this kind's parameters in params")
        for key in ("file", "class_name"):
            value = getattr(self, key)
            self._only_for(key, value is not None and self.kind != USER_KIND, "is only for kind 'python'")
            if self.kind == USER_KIND and (not isinstance(value, str) or not value):
                raise ControllerError(f"controller {key.replace('_name', '')} is required with kind "
                                      f"'python' (a string), got {value!r}")
        self._check_look_ahead()
        self.kind_params()   # checks the kind's parameters now, not when the run starts

    def _check_look_ahead(self) -> None:
        value = self.look_ahead_s
        if not (value is None or value == LOOK_AHEAD_AUTO or in_range(value, 0.0, LOOK_AHEAD_MAX_S)):
            raise ControllerError(f"controller look_ahead_s must be \"{LOOK_AHEAD_AUTO}\" or a number in "
                                  f"[0, {LOOK_AHEAD_MAX_S:g}] s, got {value!r}")
        if not in_range(self.look_ahead_tune, 0.0, 1.0):
            raise ControllerError(f"controller look_ahead_tune must be a number in [0, 1], "
                                  f"got {self.look_ahead_tune!r}")

    def _only_for(self, key: str, given: bool, why: str) -> None:
        if given:
            raise ControllerError(f"controller {key} {why} (kind is {self.kind!r}), "
                                  f"got {getattr(self, key)!r}")

    @property
    def registry_kind(self) -> str:
        """The registered kind this configuration runs ("pid" for P, PI, PID)."""
        return "pid" if self.kind in PID_KINDS else self.kind

    def kind_params(self):
        """The kind's checked parameters, an instance of its params dataclass (`PidParams` for P, PI,
        PID; `PythonParams` with file, class and the user's unchecked dict for kind "python")."""
        kind = registry.get(self.registry_kind)
        if self.kind in PID_KINDS:
            return kind.params(terms=PID_KINDS[self.kind], **{k: getattr(self, k) for k in PID_KEYS})
        if self.kind == USER_KIND:
            return kind.params(file=self.file, class_name=self.class_name, params=dict(self.params))
        return kind.params.from_dict(self.params)

    def resolved(self, base_dir: str) -> ControllerConfig:
        """A copy whose `file` is absolute, relative paths taken from `base_dir` (the scenario's folder)."""
        if self.file is None or os.path.isabs(self.file):
            return self
        return replace(self, file=os.path.normpath(os.path.join(base_dir, self.file)))

    @classmethod
    def from_table(cls, table: dict, base_dir: str | None = None) -> ControllerConfig:
        """Build from a TOML ``[controller]`` table (key ``class`` -> `class_name`), resolving `file`
        against `base_dir` if given. Unknown keys are a `ControllerError` naming them."""
        if not isinstance(table, dict):
            raise ControllerError(f"[controller] must be a table, got {table!r}")
        known = {f.name for f in fields(cls)} - {"class_name"} | {"class"}
        for key in table:
            if key not in known:
                raise ControllerError(f"controller: unknown key {key!r} (known: {', '.join(sorted(known))})")
        args = {("class_name" if k == "class" else k): v for k, v in table.items()}
        cfg = cls(**args)
        return cfg.resolved(base_dir) if base_dir is not None else cfg
