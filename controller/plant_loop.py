"""The closed loop around any controller: speed sensor -> controller -> saturated valve current -> plant.

The same plant, sensor gain and delay line, and current saturation as the PID's lifted-matrix loop
(`controller.loop`), but with the controller outside the matrix: the plant alone is lifted over one
control period T (`controller.discretize.lift`, exact ZOH of the 1 ms model), and the controller is
called once per period with arrays of all n loops. One period is

1. ``y_m`` = head of the sensor delay line (the shaft speed at ``k T - tau``),
2. ``I = clip(controller.step(clip(r), y_m))`` (``step(clip(r), y_m, context)`` for a controller whose
   step takes the context, `controller.context`),
3. ``[x', rev, sample, rpm] = L [x, I, T_L]`` (one product for all loops), and the new sensor sample
   (taken inside this period, at the delay's offset) enters the delay line's tail.

One loop (n = 1, the field run) takes a leaner path with the same arithmetic: per period only the
state and the sensor sample are computed (one product of six), the controller gets floats when it
offers ``step_one`` (the built-in kinds, `controller.interface.LawController`), and the outputs
(speed, revolutions) are computed for the whole run afterwards in one product, from the recorded
states and currents. It agrees with the n-loop path to rounding (1e-12).
"""

from __future__ import annotations

import itertools

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.context import ContextTrack, ControlContext, takes_context
from vrsim.controller.discretize import lift
from vrsim.controller.interface import LoopInfo, state_arrays
from vrsim.controller.loop_io import StepOutput, clip_targets, targets_matrix
from vrsim.controller.plant import IX_ANGLE, N_STATES, shaft_rev_row, shaft_rpm_row, state_space

# Columns of the lifted product's output after the next state (rows of `Lifted.step`).
OUT_REV, OUT_SAMPLE, OUT_RPM = N_STATES, N_STATES + 1, N_STATES + 2


class PlantLoop:
    """n loops of the plant in `info` closed by `controller` (any object with the interface).

    Parameters
    ----------
    info : LoopInfo
        Plant, control period T and plant step h (T must be a whole multiple of h).
    controller
        A controller for n loops (`controller.interface`).
    n : int
        Number of loops; must be the controller's.
    record_fine : bool
        Also compute the shaft speed at every plant step (`step_fine`), for step responses.

    Notes
    -----
    Same outputs, `state`/`set_state`, `reset`, `run` and `step_fine` as `controller.ClosedLoop`;
    its state is a dict ``{"plant_x": (n, 5), "delay_rpm": (n, d), "periods": int, "controller": {...}}``
    (``periods`` since the start: the context's time).
    """

    def __init__(self, info: LoopInfo, controller, n: int = 1, record_fine: bool = False):
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ControllerError(f"n must be a positive integer, got {n!r}")
        p = info.plant
        A, B = state_space(p)
        lifted = lift(A, B, shaft_rpm_row(p), shaft_rev_row(p), info.control_period_s, info.plant_step_s,
                      p.sensor_delay_s)
        self.info = info
        self.controller = controller
        self.n = n
        self.control_period_s = info.control_period_s
        self.plant_step_s = info.plant_step_s
        self.n_fine = lifted.fine.shape[0]
        self._LT = np.ascontiguousarray(lifted.step.T)          # (nx + 2, nx + 3)
        # one loop: [x, I] -> [x', sample] per period (the load's share added per run); the outputs
        # [rev, rpm] from [x, I, load] once per run
        self._next_T = np.ascontiguousarray(self._LT[:N_STATES + 1, [*range(N_STATES), OUT_SAMPLE]])
        self._next_load = self._LT[N_STATES + 1, [*range(N_STATES), OUT_SAMPLE]]
        self._outputs_T = np.ascontiguousarray(self._LT[:, [OUT_RPM, OUT_REV]])
        self._FT = np.ascontiguousarray(lifted.fine.T) if record_fine else None
        self._z = np.zeros((n, N_STATES + 2))                   # [x, current, load] of this period
        self._ring = np.zeros((n, lifted.delay_periods))        # sensor readings, oldest first
        self._rmax, self._ilo, self._ihi = p.shaft_rpm_max, p.current_min_a, p.current_max_a
        self._with_context = takes_context(controller.step)     # once, never per period
        self._periods = 0

    # -- state -------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to rest: plant, delay line and controller."""
        self._z[:] = 0.0
        self._ring[:] = 0.0
        self._periods = 0
        self.controller.reset()

    @property
    def state(self) -> dict:
        """Plant state, sensor delay line and the controller's state, as plain data (copies)."""
        return {"plant_x": self._z[:, :N_STATES].copy(), "delay_rpm": self._ring.copy(),
                "periods": self._periods, "controller": self.controller.state()}

    def set_state(self, state: dict) -> None:
        """Restore a state obtained from `state` (arrays may be lists, as after JSON)."""
        got = state_arrays(state, {"plant_x": (self.n, N_STATES), "delay_rpm": self._ring.shape}, "loop")
        for key in ("controller", "periods"):
            if key not in state:
                raise ControllerError(f"loop state has no {key!r}")
        self.controller.set_state(state["controller"])
        self._periods = int(state["periods"])
        self._z[:, :N_STATES] = got["plant_x"]
        self._ring[:] = got["delay_rpm"]

    @property
    def motor_angle_rad(self) -> np.ndarray:
        """Total motor angle since rest [rad], shape (n,)."""
        return self._z[:, IX_ANGLE].copy()

    # -- stepping ----------------------------------------------------------------------------------------
    def step(self, target_shaft_rpm, load_torque_nm=0.0) -> StepOutput:
        """Advance one control period; arguments and result as `controller.ClosedLoop.step` (a
        context-taking controller gets no drive: NaN speed and rate, `run` gives one)."""
        r = clip_targets(target_shaft_rpm, self.n, self._rmax)
        drive = tuple(a[0] for a in self._drive(None, 1)) if self._with_context else None
        out, cur, measured = self._advance(r, load_torque_nm, drive)
        return StepOutput(out[:, OUT_RPM], out[:, OUT_REV], cur, measured)

    def run(self, targets_rpm, load_torque_nm=0.0, context: ContextTrack | None = None) -> StepOutput:
        """`step` once per row of `targets_rpm` ((K,) for n = 1, or (K, n)); outputs of shape (K, n).

        `context` is the drive's part of a context-taking controller's `ControlContext` for these K
        periods (None: unknown, NaN); other controllers never see it.
        """
        t = targets_matrix(targets_rpm, self.n)
        r_all = clip_targets(t.ravel(), t.size, self._rmax).reshape(t.shape)
        drive = self._drive(context, t.shape[0])
        if self.n == 1:
            return self._run_one(r_all[:, 0], float(np.broadcast_to(load_torque_nm, (1,))[0]), drive)
        rec = np.empty((4, t.shape[0], self.n))
        advance = self._advance
        rows = zip(*drive, strict=True) if drive else itertools.repeat(None)    # period k's context rows
        for k, row in zip(range(t.shape[0]), rows, strict=False):   # repeat(None) has no end
            out, rec[2, k], rec[3, k] = advance(r_all[k], load_torque_nm, row)
            rec[0, k], rec[1, k] = out[:, OUT_RPM], out[:, OUT_REV]
        return StepOutput(rec[0], rec[1], rec[2], rec[3])

    def _drive(self, context: ContextTrack | None, periods: int) -> tuple:
        """The drive's context per period and loop ((K, n), (K, n), (K, n, S)); () for a controller
        that takes none."""
        if not self._with_context:
            return ()
        track = ContextTrack.unknown(periods) if context is None else context
        if len(track.speed_m_s) != periods:
            raise ControllerError(f"context must cover the {periods} periods, got {len(track.speed_m_s)}")
        return track.per_loop(self.n)

    def _context(self, period: int, r, measured, speed, rate, sections) -> ControlContext:
        """The context of period `period` since the start (its time) for targets `r` and readings."""
        return ControlContext(r, measured, speed, rate, sections, period * self.control_period_s,
                              self.info.plant.shaft_rpm_per_a)

    def _run_one(self, r_all: np.ndarray, load: float, drive: tuple) -> StepOutput:
        """`run` for one loop: per period the controller and ``[x', sample] = [x, I] N`` only."""
        k_all = len(r_all)
        xi = np.empty((k_all, N_STATES + 2))           # [x, I, load] at the start of each period
        xi[:, N_STATES + 1] = load
        measured = np.empty(k_all)
        ring = self._ring[0].tolist()
        depth = len(ring)
        head = 0                                       # ring[head] is the oldest reading
        z = self._z[0, :N_STATES + 1].copy()           # [x, I]
        next_t, load_term = self._next_T, self._next_load * load
        ilo, ihi = self._ilo, self._ihi
        ctrl = self.controller
        one = None if drive else getattr(ctrl, "step_one", None)
        start = self._periods
        for k, r in enumerate(r_all.tolist()):
            m = ring[head]
            if one is not None:
                cur = one(r, m)
            else:
                if drive:
                    target, reading = np.array((r,)), np.array((m,))
                    context = self._context(start + k, target, reading, *(a[k] for a in drive))
                    out = ctrl.step(target, reading, context)
                else:
                    out = ctrl.step(np.array((r,)), np.array((m,)))
                if not (isinstance(out, np.ndarray) and out.shape == (1,)):
                    out = as_loop_currents(out, 1, ctrl)
                cur = float(out[0])
            cur = ilo if cur < ilo else (ihi if cur > ihi else cur)
            z[N_STATES] = cur
            xi[k, :N_STATES + 1] = z
            measured[k] = m
            new = z @ next_t + load_term
            z[:N_STATES] = new[:N_STATES]
            ring[head] = float(new[N_STATES])
            head = head + 1 if head + 1 < depth else 0
        self._periods = start + k_all
        self._z[0, :N_STATES + 1] = z
        self._z[0, N_STATES + 1] = load
        self._ring[0] = ring[head:] + ring[:head]
        outputs = xi @ self._outputs_T
        return StepOutput(outputs[:, :1], outputs[:, 1:], xi[:, N_STATES:N_STATES + 1], measured[:, None])

    def step_fine(self, target_shaft_rpm, load_torque_nm=0.0) -> tuple[StepOutput, np.ndarray]:
        """`step`, plus the shaft speed at each plant step of the period, shape (n, N) [rpm]."""
        if self._FT is None:
            raise ControllerError("step_fine needs a loop built with record_fine=True")
        z0 = self._z.copy()
        so = self.step(target_shaft_rpm, load_torque_nm)
        z0[:, N_STATES:] = self._z[:, N_STATES:]   # this period's current and load
        return so, z0 @ self._FT

    def _advance(self, r, load, drive=None):
        """One period with clipped targets `r` and, for a controller that takes it, the drive's context
        (speed, rate, sections: a row of each of `_drive`'s arrays): (product output, applied current,
        reading used)."""
        measured = self._ring[:, 0].copy()
        if drive is None:
            cur = self.controller.step(r, measured)
        else:
            cur = self.controller.step(r, measured, self._context(self._periods, r, measured, *drive))
        self._periods += 1
        if not (isinstance(cur, np.ndarray) and cur.shape == (self.n,)):
            cur = as_loop_currents(cur, self.n, self.controller)
        cur = np.minimum(np.maximum(cur, self._ilo), self._ihi)
        z = self._z
        z[:, N_STATES] = cur
        z[:, N_STATES + 1] = load
        out = z @ self._LT
        z[:, :N_STATES] = out[:, :N_STATES]
        ring = self._ring
        ring[:, :-1] = ring[:, 1:]
        ring[:, -1] = out[:, OUT_SAMPLE]
        return out, cur, measured


def as_loop_currents(current, n: int, controller) -> np.ndarray:
    """A controller's output as finite floats of shape (n,) (a scalar is broadcast); a `ControllerError`
    naming the controller otherwise. `PlantLoop` trusts the built-in kinds' arrays; user code is
    checked every period (`controller.kinds.python`)."""
    name = getattr(controller, "name", type(controller).__name__)
    if isinstance(current, np.ndarray) and current.shape == (n,) and current.dtype == np.float64:
        out = current.copy()      # the usual answer: spare broadcast_to (a few microseconds per period)
    else:
        try:
            out = np.broadcast_to(np.asarray(current, dtype=float), (n,)).copy()
        except (TypeError, ValueError):
            raise ControllerError(f"{name}.step must return {n} currents [A], got {current!r}") from None
    if not np.isfinite(out).all():
        raise ControllerError(f"{name}.step must return finite currents [A], got {out!r}")
    return out
