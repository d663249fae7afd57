"""The numbers Liang et al. (2013) print, and the paper's own tuning formulas, verbatim.

Kept apart from the model so that every comparison "paper vs vrsim" reads its paper side from one place.
Symbols follow the paper; its labels for the ultimate gain and period are swapped in the text
("oscillating period Km = 0.955", "oscillation gain Tm = 0.31 s"): here `KU` is the gain and `TU_S`
the period, which is the only reading under which its Kp = 0.6 Km = 0.573 holds.
"""

from __future__ import annotations

KU = 0.955            # ultimate (critical) proportional gain [V/V]
TU_S = 0.31           # ultimate oscillation period [s]
SAMPLE_S = 0.05       # controller sampling period T [s]

# Printed section 4 results (eqs. 15-17).
KP = 0.573
KI = 0.1848           # the paper's "integral coefficient" Kp T / (0.5 Tm): dimensionless, per sample
KD = 0.0011           # the paper's "differential coefficient" 0.125 Kp T Tm
A = 0.6795
B = 0.5742
C = 0.0006

# Printed section 5 simulation results (Figs. 5-7): overshoot [%] and settling ("adjust") time [s].
STEP = {
    "P": {"overshoot_pct": 78.38, "settling_s": 6.3},
    "PI": {"overshoot_pct": 53.21, "settling_s": 3.75},
    "PID": {"overshoot_pct": 27.92, "settling_s": 1.7},
}
# Section 6 bench test (Figs. 9-10); the PID overshoot is missing from the text ("overshoot is %").
BENCH = {"PI": {"overshoot_pct": 31.5, "settling_s": 5.3}, "PID": {"overshoot_pct": None, "settling_s": 2.7}}


def formula_coefficients(ku: float = KU, tu_s: float = TU_S, sample_s: float = SAMPLE_S) -> dict[str, float]:
    """The paper's eqs. 15-17 as written: Kp, Ki, Kd and the incremental coefficients A, B, C.

    ``Kp = 0.6 Ku``, ``Ki = Kp T / (0.5 Tu)``, ``Kd = 0.125 Kp T Tu``, then ``A = Kp (1 + Ki + Kd)``,
    ``B = Kp (1 + 2 Kd)``, ``C = Kp Kd``. Note that Kp multiplies Ki and Kd twice (once inside them,
    once in A, B, C), and Kd is not Td/T: this is what the paper computes, not textbook Ziegler-Nichols.
    """
    kp = 0.6 * ku
    ki = kp * sample_s / (0.5 * tu_s)
    kd = 0.125 * kp * sample_s * tu_s
    return {"Kp": kp, "Ki": ki, "Kd": kd, "A": kp * (1 + ki + kd), "B": kp * (1 + 2 * kd), "C": kp * kd}
