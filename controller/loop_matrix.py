"""The one matrix of a closed-loop tick (`controller.loop.ClosedLoop`): the augmented state's layout
``s = [plant x (5), sensor delay line (D), pid (5)]``, the product matrix M that advances it by one
control period (exact ZOH plant, delay-line shift with the new sensor sample, PID memory, outputs),
and the PID law's gain vectors over that state (`controller.pid_law.pid_rows` with the error and the
measurement substituted).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.discretize import Lifted, lift
from vrsim.controller.plant import N_STATES, PlantParams, shaft_rev_row, shaft_rpm_row, state_space

__all__ = ["ACC", "E1", "E2", "IN_CURRENT", "IN_LOAD", "IN_TARGET", "N_PID", "OUT_CURRENT", "OUT_MEASURED",
           "OUT_REV", "OUT_RPM", "Y1", "Y2", "Layout", "gain_vectors", "per_loop", "plant_block",
           "values_of"]

N_PID = 5
ACC, E1, E2, Y1, Y2 = range(N_PID)
# Extra entries of the product's input after the state, and extra rows of its output after the state.
IN_CURRENT, IN_TARGET, IN_LOAD = range(3)
OUT_REV, OUT_RPM, OUT_CURRENT, OUT_MEASURED = range(4)

class Layout:
    """Index arithmetic of the augmented state for a delay line of D samples."""

    def __init__(self, delay_slots: int):
        self.D = delay_slots
        self.ring0 = N_STATES
        self.pid0 = N_STATES + delay_slots
        self.ns = self.pid0 + N_PID          # state size
        self.nv = self.ns + 3                 # product input size: state, current, target, load


def plant_block(p: PlantParams, lay: Layout, form: str, control_period_s: float,
                 plant_step_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The product matrix M (ns + 7, nv) and the fine-output rows F (N, nv) for one plant.

    M's rows: the next state (ns), three zero rows where the next tick writes its inputs (so the product
    is directly the next tick's vector), and the outputs (4).
    """
    A, B = state_space(p)
    lifted = lift(A, B, shaft_rpm_row(p), shaft_rev_row(p), control_period_s, plant_step_s,
                  p.sensor_delay_s)
    d = lifted.delay_periods
    ns, nv, r0, p0 = lay.ns, lay.nv, lay.ring0, lay.pid0
    cur, tgt, load = ns + IN_CURRENT, ns + IN_TARGET, ns + IN_LOAD
    ks, ka = p.sensor_gain_v_per_rpm, p.amplifier_gain_a_per_v
    out0 = ns + 3
    M = np.zeros((out0 + 4, nv))
    xu = list(range(N_STATES)) + [cur, load]     # columns that the lifted rows act on
    M[:N_STATES, xu] = lifted.step[:N_STATES]
    for j in range(d - 1):                       # delay line shifts towards its head
        M[r0 + j, r0 + j + 1] = 1.0
    M[r0 + d - 1, xu] = lifted.step[Lifted.ROW_SAMPLE]
    if form == "incremental":
        M[p0 + ACC, cur] = 1.0 / ka               # u(n-1) <- saturated output in volts
    else:
        M[p0 + ACC, p0 + ACC] = 1.0               # error sum += e
        M[p0 + ACC, tgt], M[p0 + ACC, r0] = ks, -ks
    M[p0 + E1, tgt], M[p0 + E1, r0] = ks, -ks     # e1 <- e = Ks (r - y_m)
    M[p0 + E2, p0 + E1] = 1.0
    M[p0 + Y1, r0] = ks                           # y1 <- Ks y_m
    M[p0 + Y2, p0 + Y1] = 1.0
    M[out0 + OUT_REV, xu] = lifted.step[Lifted.ROW_REV]
    M[out0 + OUT_RPM, xu] = lifted.step[Lifted.ROW_RPM]
    M[out0 + OUT_CURRENT, cur] = 1.0
    M[out0 + OUT_MEASURED, r0] = 1.0
    F = np.zeros((lifted.fine.shape[0], nv))
    F[:, xu] = lifted.fine
    return M, F


def gain_vectors(rows: np.ndarray, ks: np.ndarray, lay: Layout) -> tuple[np.ndarray, np.ndarray]:
    """Turn `pid_rows` into (g over the state (n, ns), g_r on the target (n,)), substituting
    e = Ks r - Ks y_m and y = Ks y_m."""
    a_acc, a_e, a_e1, a_e2, a_y, a_y1, a_y2 = rows.T
    g = np.zeros((rows.shape[0], lay.ns))
    p0 = lay.pid0
    g[:, p0 + ACC], g[:, p0 + E1], g[:, p0 + E2], g[:, p0 + Y1], g[:, p0 + Y2] = a_acc, a_e1, a_e2, a_y1, a_y2
    g[:, lay.ring0] = ks * (a_y - a_e)
    return g, ks * a_e


def per_loop(value, n: int, name: str) -> list:
    if isinstance(value, Sequence) and not isinstance(value, str):
        if len(value) != n:
            raise ControllerError(f"{name} must be one value or {n} values (n={n}), got {len(value)}")
        return list(value)
    return [value] * n


def values_of(source: list, name: str, n: int) -> np.ndarray:
    """Attribute `name` of each loop's object, shape (n,); `source` is n objects or one shared one."""
    values = [getattr(x, name) for x in source]
    return np.array(values if len(source) == n else values * n, dtype=float)
