"""PID gains and two of their sources: the paper's printed numbers and the Ziegler-Nichols table.

Gains are kept in the parallel continuous form ``u = kp e + ki integral(e) dt + kd de/dt`` with the
error e and output u in volts (sensor volts in, amplifier volts out, as in the paper's Fig. 3):
``kp`` [V/V], ``ki`` [1/s], ``kd`` [s]. At a sampling period T they become the per-sample
coefficients of the paper's incremental law ``du(n) = A e(n) - B e(n-1) + C e(n-2)`` with
``A = kp + ki T + kd/T``, ``B = kp + 2 kd/T``, ``C = kd/T``.
"""

from __future__ import annotations

from dataclasses import dataclass

from vrsim.common import ControllerError
from vrsim.controller import liang2013

TERMS = ("P", "PI", "PID")   # which terms a PID uses
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


def ziegler_nichols(terms: str, ku: float, tu_s: float) -> PidGains:
    """Classic Ziegler-Nichols ultimate-gain table.

    P: kp = 0.5 Ku. PI: kp = 0.45 Ku, Ti = Tu/1.2. PID: kp = 0.6 Ku, Ti = Tu/2, Td = Tu/8.
    Returned in parallel form (ki = kp/Ti [1/s], kd = kp Td [s]).
    """
    if not (ku > 0 and tu_s > 0):
        raise ControllerError(f"Ziegler-Nichols needs Ku > 0 and Tu > 0, got Ku={ku!r}, Tu={tu_s!r}")
    if terms == "P":
        return PidGains(kp=0.5 * ku)
    if terms == "PI":
        kp = 0.45 * ku
        return PidGains(kp=kp, ki=kp / (tu_s / 1.2))
    if terms == "PID":
        kp = 0.6 * ku
        return PidGains(kp=kp, ki=kp / (tu_s / 2.0), kd=kp * tu_s / 8.0)
    raise ControllerError(f"terms must be one of {', '.join(TERMS)}, got {terms!r}")


def paper_gains(terms: str) -> PidGains:
    """The paper's printed gains as it uses them, at its sampling period T = 50 ms.

    PID: printed A, B, C exactly. PI: eq. 16 with Kd = 0, i.e. A = Kp (1 + Ki), B = Kp. P: Kp.
    The paper prints only the PID set; using its Kp and Ki for P and PI is our reading of Figs. 5-6.
    """
    t = liang2013.SAMPLE_S
    if terms == "PID":
        return PidGains.from_incremental(liang2013.A, liang2013.B, liang2013.C, t)
    if terms == "PI":
        return PidGains.from_incremental(liang2013.KP * (1 + liang2013.KI), liang2013.KP, 0.0, t)
    if terms == "P":
        return PidGains(kp=liang2013.KP)
    raise ControllerError(f"terms must be one of {', '.join(TERMS)}, got {terms!r}")
