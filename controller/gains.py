"""Controller configuration and where its gains come from: the paper, Ziegler-Nichols, relay, manual.

Gains are kept in the parallel continuous form ``u = kp e + ki integral(e) dt + kd de/dt`` with the
error e and output u in volts (sensor volts in, amplifier volts out, as in the paper's Fig. 3):
``kp`` [V/V], ``ki`` [1/s], ``kd`` [s]. At a sampling period T they become the per-sample
coefficients of the paper's incremental law ``du(n) = A e(n) - B e(n-1) + C e(n-2)`` with
``A = kp + ki T + kd/T``, ``B = kp + 2 kd/T``, ``C = kd/T``.
"""

from __future__ import annotations

from dataclasses import dataclass

from common import ControllerError, check_number
from controller import liang2013

KINDS = ("P", "PI", "PID")
FORMS = ("incremental", "positional")
GAIN_SOURCES = ("paper", "textbook", "relay", "manual")
# Far above any useful gain (the paper's PID: kp 0.57 V/V, ki 2.1 /s), and far below where
# kp * error overflows a float64 in the loop (1e308 turns the valve current into NaN).
MAX_GAIN = 1e6


@dataclass(frozen=True)
class PidGains:
    """Parallel PID gains: kp [V/V], ki [1/s], kd [s]."""

    kp: float
    ki: float = 0.0
    kd: float = 0.0

    def incremental(self, sample_s: float) -> tuple[float, float, float]:
        """The paper's (A, B, C) at sampling period `sample_s` [s]."""
        ki_t, kd_t = self.ki * sample_s, self.kd / sample_s
        return self.kp + ki_t + kd_t, self.kp + 2.0 * kd_t, kd_t

    @classmethod
    def from_incremental(cls, a: float, b: float, c: float, sample_s: float) -> PidGains:
        """Inverse of `incremental`: kp = B - 2C, ki T = A - B + C, kd / T = C."""
        return cls(kp=b - 2.0 * c, ki=(a - b + c) / sample_s, kd=c * sample_s)


@dataclass(frozen=True)
class ControllerConfig:
    """Which controller runs the valve.

    Parameters
    ----------
    kind : {"P", "PI", "PID"}
    form : {"incremental", "positional"}
        Incremental: the paper's velocity form, anti-windup by holding the saturated output.
        Positional: integral sum with conditional integration (clamping) when saturated.
    gains : {"paper", "textbook", "relay", "manual"}
        "paper": the paper's printed numbers (PID: A, B, C; PI: its Kp and Ki with Kd = 0; P: its Kp).
        "textbook": classic Ziegler-Nichols table from the paper's Ku = 0.955, Tu = 0.31 s.
        "relay": Ziegler-Nichols table from an Astrom-Hagglund relay experiment on the plant model.
        "manual": `kp` [V/V], `ki` [1/s], `kd` [s] as given.
    kp, ki, kd : float or None
        Only with ``gains="manual"``; ki needs kind PI or PID, kd kind PID.
    derivative_on_measurement : bool
        Differentiate the measured speed instead of the error (no derivative kick on setpoint steps).
    """

    kind: str = "PID"
    form: str = "incremental"
    gains: str = "paper"
    kp: float | None = None
    ki: float | None = None
    kd: float | None = None
    derivative_on_measurement: bool = False

    def __post_init__(self):
        for name, allowed in (("kind", KINDS), ("form", FORMS), ("gains", GAIN_SOURCES)):
            value = getattr(self, name)
            if value not in allowed:
                raise ControllerError(f"controller {name} must be one of {', '.join(allowed)}, got {value!r}")
        if not isinstance(self.derivative_on_measurement, bool):
            raise ControllerError(f"controller derivative_on_measurement must be true or false, "
                                  f"got {self.derivative_on_measurement!r}")
        given = {k: getattr(self, k) for k in ("kp", "ki", "kd") if getattr(self, k) is not None}
        if self.gains != "manual":
            if given:
                name = next(iter(given))
                raise ControllerError(f"controller {name} is only used with gains='manual' "
                                      f"(gains is {self.gains!r}), got {given[name]!r}")
            return
        if "kp" not in given:
            raise ControllerError("controller kp is required with gains='manual', got None")
        for name, value in given.items():
            check_number(value, f"controller {name}", ControllerError, lo=0.0, hi=MAX_GAIN)
        if given.get("ki") and "I" not in self.kind:
            raise ControllerError(f"controller ki needs kind PI or PID (kind is {self.kind!r}), "
                                  f"got {self.ki!r}")
        if given.get("kd") and "D" not in self.kind:
            raise ControllerError(f"controller kd needs kind PID (kind is {self.kind!r}), got {self.kd!r}")


def ziegler_nichols(kind: str, ku: float, tu_s: float) -> PidGains:
    """Classic Ziegler-Nichols ultimate-gain table.

    P: kp = 0.5 Ku. PI: kp = 0.45 Ku, Ti = Tu/1.2. PID: kp = 0.6 Ku, Ti = Tu/2, Td = Tu/8.
    Returned in parallel form (ki = kp/Ti [1/s], kd = kp Td [s]).
    """
    if not (ku > 0 and tu_s > 0):
        raise ControllerError(f"Ziegler-Nichols needs Ku > 0 and Tu > 0, got Ku={ku!r}, Tu={tu_s!r}")
    if kind == "P":
        return PidGains(kp=0.5 * ku)
    if kind == "PI":
        kp = 0.45 * ku
        return PidGains(kp=kp, ki=kp / (tu_s / 1.2))
    if kind == "PID":
        kp = 0.6 * ku
        return PidGains(kp=kp, ki=kp / (tu_s / 2.0), kd=kp * tu_s / 8.0)
    raise ControllerError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")


def paper_gains(kind: str) -> PidGains:
    """The paper's printed gains as it uses them, at its sampling period T = 50 ms.

    PID: printed A, B, C exactly. PI: eq. 16 with Kd = 0, i.e. A = Kp (1 + Ki), B = Kp. P: Kp.
    The paper prints only the PID set; using its Kp and Ki for P and PI is our reading of Figs. 5-6.
    """
    t = liang2013.SAMPLE_S
    if kind == "PID":
        return PidGains.from_incremental(liang2013.A, liang2013.B, liang2013.C, t)
    if kind == "PI":
        return PidGains.from_incremental(liang2013.KP * (1 + liang2013.KI), liang2013.KP, 0.0, t)
    if kind == "P":
        return PidGains(kp=liang2013.KP)
    raise ControllerError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")


def resolve_gains(cfg: ControllerConfig, plant=None,
                  control_period_s: float = liang2013.SAMPLE_S) -> PidGains:
    """The gains `cfg` asks for. ``gains="relay"`` runs the relay experiment on `plant` (a PlantParams)."""
    if cfg.gains == "paper":
        return paper_gains(cfg.kind)
    if cfg.gains == "textbook":
        return ziegler_nichols(cfg.kind, liang2013.KU, liang2013.TU_S)
    if cfg.gains == "relay":
        from controller.tuning import relay_autotune  # tuning simulates loops: import only when asked

        result = relay_autotune(plant, control_period_s=control_period_s)
        return ziegler_nichols(cfg.kind, result.ku, result.tu_s)
    return PidGains(kp=float(cfg.kp), ki=float(cfg.ki or 0.0), kd=float(cfg.kd or 0.0))
