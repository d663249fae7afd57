"""The closed loop (speed sensor -> PID -> saturated valve current -> plant) over n loops at once.

Everything in one control period is linear except the current saturation, so the loop keeps one
augmented state per loop, ``s = [plant x (5), sensor delay line (D), pid (5)]``, and a tick is

1. ``u = g . s + g_r r`` (the PID's unsaturated output, linear in state and target),
2. ``I = clip(Ka u)`` (the valve current limits),
3. ``[s', outputs] = M [s, I, r, T_L]`` (one precomputed matrix: exact ZOH plant over the period,
   delay-line shift with the new sensor sample, PID memory, and the outputs).

PID memory ``[acc, e1, e2, y1, y2]`` (volts): ``acc`` is the previous saturated output u(n-1) for the
incremental form (which is its anti-windup) and the error sum for the positional form (whose clamping
anti-windup is the one nonlinear correction after the product). The law's rows, saturation and
anti-windup are `controller.pid_law`'s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.discretize import delay_split
from vrsim.controller.gains import FORMS, PidGains
from vrsim.controller.loop_io import StepOutput, clip_targets, targets_matrix
from vrsim.controller.loop_matrix import (
    ACC,
    IN_CURRENT,
    IN_LOAD,
    IN_TARGET,
    OUT_CURRENT,
    OUT_MEASURED,
    OUT_REV,
    OUT_RPM,
    Layout,
    gain_vectors,
    per_loop,
    plant_block,
    values_of,
)
from vrsim.controller.pid_law import clamped, pid_rows, pid_terms, saturate
from vrsim.controller.plant import N_STATES, PlantParams

# n loops of one plant: the floats of the products held before their outputs are recorded (a block of
# ticks that stays in the cache), and the most loops whose PID law runs in Python floats (up to here
# their arithmetic costs less than a numpy call).
SHARED_BLOCK_FLOATS = 1 << 16
# Beyond this many loops `einsum` sums the PID law's four products in one pass over memory, faster
# than a product and a sum (and the same sums in the same order; below it its call costs more).
EINSUM_LAW_LOOPS = 1000
FLOAT_LAW_LOOPS = 4



class ClosedLoop:
    """n independent sensor-PID-valve-motor loops advancing one control period per `step`.

    Parameters
    ----------
    plants : PlantParams or sequence of n PlantParams
    gains : PidGains or sequence of n PidGains
    form : {"incremental", "positional"}
    derivative_on_measurement : bool
    control_period_s, plant_step_s : float
        Controller period T and plant step h [s]; T must be a whole multiple of h.
    n : int
        Number of loops.
    record_fine : bool
        Also return the shaft speed at every plant step (`step_fine`), for step responses.

    Notes
    -----
    Deterministic and self-contained: `state` and `set_state` capture everything, there is no clock.
    """

    def __init__(self, plants, gains, form: str = "incremental", derivative_on_measurement: bool = False,
                 control_period_s: float = 0.05, plant_step_s: float = 0.001, n: int = 1,
                 record_fine: bool = False):
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ControllerError(f"n must be a positive integer, got {n!r}")
        if form not in FORMS:
            raise ControllerError(f"form must be one of {', '.join(FORMS)}, got {form!r}")
        plant_list = per_loop(plants, n, "plants")
        gain_list = per_loop(gains, n, "gains")
        for t in set(map(type, plant_list)):
            if t is not PlantParams:
                raise ControllerError(f"plants must be PlantParams, got {t.__name__}")
        for g in set(map(type, gain_list)):
            if g is not PidGains:
                raise ControllerError(f"gains must be PidGains, got {g.__name__}")
        self.n = n
        self.form = form
        self.control_period_s = float(control_period_s)
        self.plant_step_s = float(plant_step_s)
        unique = list(dict.fromkeys(plant_list)) if isinstance(plants, Sequence) else [plants]
        self._lay = lay = Layout(max(delay_split(p.sensor_delay_s, control_period_s)[0] for p in unique))
        blocks = {p: plant_block(p, lay, form, control_period_s, plant_step_s) for p in unique}
        shared = len(unique) == 1
        M = blocks[unique[0]][0] if shared else np.stack([blocks[p][0] for p in plant_list])
        F = blocks[unique[0]][1] if shared else np.stack([blocks[p][1] for p in plant_list])
        self.n_fine = F.shape[-2]
        ps = unique if shared else plant_list
        gs = gain_list if isinstance(gains, Sequence) else [gains]
        self._ka = values_of(ps, "amplifier_gain_a_per_v", n)
        self._ks = values_of(ps, "sensor_gain_v_per_rpm", n)
        self._ilo, self._ihi = values_of(ps, "current_min_a", n), values_of(ps, "current_max_a", n)
        self._rmax = values_of(ps, "shaft_rpm_max", n)
        kp, ki, kd = values_of(gs, "kp", n), values_of(gs, "ki", n), values_of(gs, "kd", n)
        rows = pid_rows(kp, ki, kd, form, derivative_on_measurement, control_period_s)
        self._g, self._gr = gain_vectors(rows, self._ks, lay)
        self._terms = pid_terms(kp, ki, kd, form, derivative_on_measurement, control_period_s)
        self._scalar = n == 1 and shared
        # With one plant and one set of gains, g . s' (the state part of the next tick's PID output) is one
        # more row of M: a tick is then one product plus a few elementwise operations.
        self._cached_u = shared and bool(np.all(self._g == self._g[0]))
        ns = lay.ns
        self._iu = M.shape[-2]
        if self._cached_u:
            M = np.vstack([M, self._g[0] @ M[:ns]])
        if self._scalar:
            self._f = (float(self._gr[0]), float(self._ka[0]), float(self._ilo[0]), float(self._ihi[0]),
                       float(self._rmax[0]), float(self._ks[0]), float(self._g[0, lay.pid0 + ACC]))
        self._fine0 = M.shape[-2]
        if record_fine:
            M = np.concatenate([M, F], axis=-2)
        self._M = np.ascontiguousarray(M)                         # (R, nv) or (n, R, nv)
        self._MT = np.ascontiguousarray(np.swapaxes(M, -1, -2))   # v @ MT for a batch
        self._record_fine = record_fine
        self._ns = ns
        self._v = np.zeros(M.shape[-2]) if self._scalar else np.zeros((n, M.shape[-2]))
        # Where the last `_run_shared_plant` call stopped: its last tick's inputs and anti-windup
        # correction, so that the next call's first tick is the one call's (None: start from the state).
        self._resume = None

    # -- state -------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to rest: plant, delay line and PID memory at zero."""
        self._v = np.zeros_like(self._v)
        self._resume = None

    @property
    def state(self) -> np.ndarray:
        """A copy of the augmented state, shape (n, ns): plant, sensor delay line, PID memory; with one
        plant and gain set also the cached PID term (shape (n, ns + 1)), so a restore is bitwise exact."""
        v = np.atleast_2d(self._v)
        if self._cached_u:
            return np.column_stack([v[:, :self._ns], v[:, self._iu]])
        return v[:, :self._ns].copy()

    def set_state(self, state) -> None:
        """Restore a state obtained from `state` (also as nested lists, as after JSON); without the
        cached PID term (shape (n, ns)) it is recomputed, equal to rounding."""
        state = np.asarray(state, dtype=float)
        shapes = [(self.n, self._ns)] + ([(self.n, self._ns + 1)] if self._cached_u else [])
        if state.shape not in shapes:
            raise ControllerError(f"state must have shape {' or '.join(map(str, shapes))}, got {state.shape}")
        self.reset()
        v = np.atleast_2d(self._v)    # a view of the 1-D vector of a single loop
        v[:, :self._ns] = state[:, :self._ns]
        if self._cached_u:
            v[:, self._iu] = state[:, self._ns] if state.shape[1] > self._ns else state @ self._g[0]

    @property
    def motor_angle_rad(self) -> np.ndarray:
        """Total motor angle since rest [rad], shape (n,)."""
        return np.atleast_2d(self._v)[:, N_STATES - 1].copy()

    # -- stepping ----------------------------------------------------------------------------------------
    def step(self, target_shaft_rpm, load_torque_nm=0.0) -> StepOutput:
        """Advance one control period.

        Parameters
        ----------
        target_shaft_rpm : float or ndarray, shape (n,)
            Metering-shaft speed setpoint [rpm]; clipped to [0, shaft_rpm_max].
        load_torque_nm : float or ndarray, shape (n,)
            External load torque on the motor during the period [N m].

        Returns
        -------
        StepOutput
            Arrays of shape (n,); views of a fresh array, never changed by later steps.
        """
        out = self._advance(target_shaft_rpm, load_torque_nm)
        o = self._ns + 3
        if out.ndim == 1:
            return StepOutput(out[o + OUT_RPM:o + OUT_RPM + 1], out[o + OUT_REV:o + OUT_REV + 1],
                              out[o + OUT_CURRENT:o + OUT_CURRENT + 1],
                              out[o + OUT_MEASURED:o + OUT_MEASURED + 1])
        return StepOutput(out[:, o + OUT_RPM], out[:, o + OUT_REV], out[:, o + OUT_CURRENT],
                          out[:, o + OUT_MEASURED])

    def run(self, targets_rpm, load_torque_nm=0.0, context=None) -> StepOutput:
        """Advance one control period per row of `targets_rpm`; the same as calling `step` per row.

        Parameters
        ----------
        targets_rpm : ndarray, shape (K,) for n = 1, or (K, n)
            Setpoint per period and loop [rpm]; one target for every loop as a broadcast view
            (``np.broadcast_to(t[:, None], (K, n))``) is taken as such, without a copy per loop.
        load_torque_nm : float or ndarray, shape (n,)
            Load torque held over the whole run [N m].
        context : controller.context.ContextTrack, optional
            The drive's context (`controller.PlantLoop.run`); the PID's law reads none of it.

        Returns
        -------
        StepOutput
            Arrays of shape (K, n): the per-period outputs, recorded without a Python object per tick.
        """
        t = targets_matrix(targets_rpm, self.n)
        o = self._ns + 3
        rec = np.empty((t.shape[0], 4, self.n))
        if self._scalar and not isinstance(load_torque_nm, np.ndarray):
            rec[:, :, 0] = self._run_scalar(t[:, 0], load_torque_nm)[:, o:o + 4]
        elif self._scalar:
            flat = rec[:, :, 0]
            advance = self._advance
            for k, target in enumerate(t[:, 0].tolist()):
                flat[k] = advance(target, load_torque_nm)[o:o + 4]
        elif self._MT.ndim == 3:
            self._run_per_plant(t, load_torque_nm, rec)
        else:
            self._run_shared_plant(t[:, :1] if t.strides[1] == 0 else t, load_torque_nm, rec)
        return StepOutput(rec[:, OUT_RPM], rec[:, OUT_REV], rec[:, OUT_CURRENT], rec[:, OUT_MEASURED])

    def _run_scalar(self, targets: np.ndarray, load) -> np.ndarray:
        """`_advance`'s one-loop path over `targets` (K,), its arithmetic unchanged (the same clip of
        the targets and the same ``gr * r``, taken over the array at once, and the same product into a
        row of a history instead of a fresh array, so bit for bit the same), with the per-tick Python
        work cut: the slots each tick reads and writes go through a memoryview of the history (no numpy
        scalar per access); the products (K, R) after each tick."""
        gr, ka, ilo, ihi, rmax, ks, g_acc = self._f
        ns, iu, M = self._ns, self._iu, self._M
        width, nin, positional = M.shape[0], ns + 3, self.form == "positional"
        ring0, acc = self._lay.ring0, self._lay.pid0 + ACC
        nan = np.flatnonzero(np.isnan(targets))
        ticks = targets[:nan[0]] if nan.size else targets
        r_all = np.where(ticks >= 0.0, np.where(ticks > rmax, rmax, ticks), 0.0)   # `_advance`'s clip
        history = np.empty((len(ticks) + 1, width))
        history[0] = self._v
        slot = memoryview(history.reshape(-1))
        product = M.dot    # the bound method: no dispatch per tick
        # Tick k reads row k (its inputs written first) and writes row k + 1; `at` is row k's offset.
        at = 0
        for r, gr_r, inputs, out in zip(r_all.tolist(), (gr * r_all).tolist(), history[:-1, :nin],
                                        history[1:], strict=True):
            unsat = ka * (slot[at + iu] + gr_r)
            slot[at + ns] = ilo if unsat < ilo else ihi if unsat > ihi else unsat
            slot[at + ns + 1] = r
            if load:     # the product leaves the input slots at zero
                slot[at + ns + 2] = load
            product(inputs, out)
            if positional:
                e = ks * (r - slot[at + ring0])
                if (unsat > ihi and e > 0) or (unsat < ilo and e < 0):   # clamping anti-windup
                    out[acc] -= e
                    out[iu] -= g_acc * e
            at += width
        self._v = history[-1].copy()
        if nan.size:
            raise ControllerError(f"target_shaft_rpm must be a number, got {float(targets[nan[0]])!r}")
        return history[1:]

    def _run_shared_plant(self, t: np.ndarray, load, rec: np.ndarray) -> None:
        """`_advance` over the rows of `t` ((K, n), or (K, 1): one target for every loop) for n loops of
        one plant, with the per-tick Python work cut (a batch of variants runs 10^5 ticks).

        The state is held transposed (a row per entry, a column per loop: each tick writes contiguous
        rows and the product goes into the next tick's: `_shared_ticks`), and the PID output is a
        weighted sum of four rows the product computes for every loop alike: the loops' gain rows are
        linear in (1, kp, ki T, kd / T) (`pid_terms`), so g . s + g_r r is those weights times four
        shared basis outputs, which the product yields from the state and the next tick's target (an
        extra input). Equal to `_advance` per tick to rounding (the sums are taken in another order). A call
        that continues the last one (nothing stepped or set in between) starts from its last tick's
        product, as one call would: a run split into calls anywhere gives the one call's numbers bit
        for bit (a loop restored from `state` starts from the state, equal to rounding).
        """
        common = t.shape[1] == 1
        r_all = np.minimum(np.maximum(t[:, 0] if common else t, 0.0), self._rmax[0] if common else self._rmax)
        if np.isnan(r_all).any():
            raise ControllerError("target_shaft_rpm must be numbers, got NaN")
        ns, ks = self._ns, self._ks
        weights, basis = self._terms
        gamma, delta = gain_vectors(basis, np.full(len(basis), ks[0]), self._lay)
        out0, w0, nin = ns + 4, ns + 8, ns + 4     # outputs, basis outputs; inputs: ..., next target
        M = self._M
        mx = np.zeros((ns + 12, nin))
        mx[:ns, :ns + 3] = M[:ns]                  # rows ns..ns+3 stay zero: the next inputs' slots
        mx[out0:out0 + 4, :ns + 3] = M[ns + 3:ns + 7]
        mx[w0:, :ns + 3] = gamma @ M[:ns]
        mx[w0:, ns + 3] = delta
        kc = np.ascontiguousarray((self._ka[:, None] * weights).T)    # (4, n): ka times the weights
        pairs = np.zeros((len(r_all), 2, 1 if common else self.n))     # (this target, the next one)
        pairs[:, 0] = r_all if not common else r_all[:, None]
        pairs[:-1, 1] = pairs[1:, 0]
        acc = self._lay.pid0 + ACC
        v = np.zeros((ns + 12, self.n))
        v[:ns] = np.atleast_2d(self._v)[:, :ns].T
        spare = np.empty_like(v)
        if len(r_all) and self._resume is not None:   # the last tick's product again, with this target
            last, held = self._resume
            last[ns + 3] = pairs[0, 0]
            np.dot(mx, last, out=spare)
            if held is not None:
                spare[w0:] -= gamma[:, acc, None] * held
            v[w0:] = spare[w0:]
        elif len(r_all):
            v[w0:] = gamma @ v[:ns] + delta[:, None] * pairs[0, 0]
        v = self._shared_ticks(v, mx, kc, gamma[:, acc], pairs, load, rec)
        state = np.zeros_like(np.atleast_2d(self._v))
        state[:, :ns] = v[:ns].T
        state[:, ns + 3:ns + 7] = v[out0:out0 + 4].T
        if self._cached_u:
            state[:, self._iu] = state[:, :ns] @ self._g[0]
        self._v = state

    def _shared_ticks(self, v: np.ndarray, mx: np.ndarray, kc: np.ndarray, g_acc: np.ndarray,
                      pairs: np.ndarray, load, rec: np.ndarray) -> np.ndarray:
        """The ticks of `_run_shared_plant`: from `v` (ns + 12, n), the state with this tick's basis
        outputs, through the product `mx` (ns + 12, ns + 4), the loops' weights `kc` (4, n), the basis
        outputs' coefficients on the error sum `g_acc` (4,) and the targets `pairs` (K, 2, 1 or n);
        the outputs go into `rec` (K, 4, n). Returns the last product and keeps `_resume`.

        Each tick's product goes straight into the next tick's vector in a history of a block of
        ticks, whose outputs are recorded a block at a time. The unsaturated PID output of a loop is
        ``0 + p0 + p1 + p2 + p3`` (in this order, each step rounded) of its four products
        ``p = kc * w`` with the basis outputs w, as ``einsum("bj,bj->j", kc, w)`` sums them: in floats
        for a few loops (`_float_law`), over arrays for many (`_array_law`).
        """
        ns, n = self._ns, self.n
        out0, w0, nin = ns + 4, ns + 8, ns + 4
        law = (self._float_law if n <= FLOAT_LAW_LOOPS else self._array_law)(kc, ns)
        with_load = isinstance(load, np.ndarray) or bool(load)
        positional, ring0, acc = self.form == "positional", self._lay.ring0, self._lay.pid0 + ACC
        ilo, ihi, ks = self._ilo, self._ihi, self._ks
        g_col = g_acc[:, None]
        dot = np.dot
        block = max(1, SHARED_BLOCK_FLOATS // v.size)
        hist = np.empty((min(block, len(pairs)) + 1, *v.shape))
        hist[0] = v
        held = None
        for start in range(0, len(pairs), block):
            m = min(block, len(pairs) - start)
            for h, nxt, pair in zip(hist[:m], hist[1:m + 1], pairs[start:start + m], strict=True):
                unsat = law(h)
                h[ns + IN_TARGET:ns + 4:2] = pair
                if with_load:
                    h[ns + IN_LOAD] = load
                dot(mx, h[:nin], out=nxt)
                held = None
                if positional:      # clamping anti-windup: the error sum and the basis outputs after it
                    e = ks * (pair[0] - h[ring0])
                    frozen = clamped(np.asarray(unsat), e, ilo, ihi)
                    if frozen.any():
                        held = np.where(frozen, e, 0.0)
                        nxt[acc] -= held
                        nxt[w0:] -= g_col * held
            rec[start:start + m] = hist[1:m + 1, out0:out0 + 4]
            if start + m == len(pairs):
                self._resume = (hist[m - 1, :nin].copy(), held)   # the last tick's inputs
            if block == 1:   # a tick a block (thousands of loops): the two vectors change places, no copy
                hist = hist[::-1]
            else:
                hist[0] = hist[m]
        return hist[0]

    def _float_law(self, kc: np.ndarray, ns: int):
        """The PID law of a few loops in Python floats (a numpy call costs more than their arithmetic):
        ``law(h)`` writes the saturated currents into row `ns` of a tick's vector `h` from its basis
        outputs and returns the unsaturated ones (a list)."""
        weights, w0 = kc.T.tolist(), ns + 8
        lo, hi = float(self._ilo[0]), float(self._ihi[0])

        def law(h):
            unsat = [0.0 + c0 * a + c1 * b + c2 * c + c3 * d
                     for (c0, c1, c2, c3), a, b, c, d in zip(weights, *h[w0:].tolist(), strict=True)]
            h[ns] = [lo if u < lo else hi if u > hi else u for u in unsat]   # `saturate` inline
            return unsat
        return law

    def _array_law(self, kc: np.ndarray, ns: int):
        """`_float_law` over arrays, for many loops: the same products and sums in the same order, by
        `einsum` beyond `EINSUM_LAW_LOOPS` loops (`tests/unit/test_controller_multiloop.py` runs them
        all on a run's targets)."""
        w0, ilo, ihi = ns + 8, self._ilo, self._ihi
        products, unsat = np.empty_like(kc), np.empty(kc.shape[1])
        multiply, add = np.multiply, np.add.reduce
        if kc.shape[1] > EINSUM_LAW_LOOPS:
            def law(h):
                unsat = np.einsum("bj,bj->j", kc, h[w0:])
                saturate(unsat, ilo, ihi, out=h[ns])
                return unsat
            return law

        def law(h):
            add(multiply(kc, h[w0:], out=products), axis=0, out=unsat, initial=0.0)
            saturate(unsat, ilo, ihi, out=h[ns])
            return unsat
        return law

    def _run_per_plant(self, t: np.ndarray, load, rec: np.ndarray) -> None:
        """`_advance` over the rows of `t` (K, n) for n loops of their own plants (one product each),
        its arithmetic unchanged, with the targets clipped at once."""
        r_all = np.minimum(np.maximum(t, 0.0), self._rmax)
        if np.isnan(r_all).any():
            raise ControllerError("target_shaft_rpm must be numbers, got NaN")
        o = self._ns + 3
        v = np.atleast_2d(self._v)
        for k in range(t.shape[0]):
            v = self._tick(v, r_all[k], load)
            rec[k] = v[:, o:o + 4].T
        self._v = v

    def step_fine(self, target_shaft_rpm, load_torque_nm=0.0) -> tuple[StepOutput, np.ndarray]:
        """`step`, plus the shaft speed at each plant step of the period, shape (n, N) [rpm].

        Needs ``record_fine=True``.
        """
        if not self._record_fine:
            raise ControllerError("step_fine needs a loop built with record_fine=True")
        out = np.atleast_2d(self._advance(target_shaft_rpm, load_torque_nm))
        o = self._ns + 3
        so = StepOutput(out[:, o + OUT_RPM], out[:, o + OUT_REV], out[:, o + OUT_CURRENT],
                        out[:, o + OUT_MEASURED])
        return so, out[:, self._fine0:]

    def _advance(self, target, load):
        v, ns = self._v, self._ns
        if self._scalar and not isinstance(target, np.ndarray) and not isinstance(load, np.ndarray):
            gr, ka, ilo, ihi, rmax, ks, g_acc = self._f
            r = float(target)
            if not r >= 0.0:
                if r != r:
                    raise ControllerError(f"target_shaft_rpm must be a number, got {target!r}")
                r = 0.0
            elif r > rmax:
                r = rmax
            # `pid_law.saturate` and `clamped` inline: a call costs a tenth of this tick (proven equal
            # by tests/unit/test_controller_law.py)
            unsat = ka * (v[self._iu] + gr * r)
            cur = ilo if unsat < ilo else ihi if unsat > ihi else unsat
            v[ns] = cur
            v[ns + 1] = r
            if load:     # the product leaves the input slots at zero
                v[ns + 2] = load
            out = self._M.dot(v[:ns + 3])
            if self.form == "positional":
                e = ks * (r - v[self._lay.ring0])
                if (unsat > ihi and e > 0) or (unsat < ilo and e < 0):   # clamping anti-windup
                    out[self._lay.pid0 + ACC] -= e
                    out[self._iu] -= g_acc * e
            self._v = out
            return out
        out = self._tick(np.atleast_2d(v), self._targets(target), load)
        self._v = out[0] if self._scalar else out
        self._resume = None
        return self._v

    def _tick(self, v: np.ndarray, r: np.ndarray, load) -> np.ndarray:
        """One period of n loops: `v` (n, R) the last product (its input slots are written), `r` (n,)
        clipped targets [rpm]; the new product (n, R). The law's output stage is `pid_law`'s."""
        ns = self._ns
        u = v[:, self._iu] if self._cached_u else np.einsum("ij,ij->i", v[:, :ns], self._g)
        unsat = self._ka * (u + self._gr * r)
        v[:, ns + IN_CURRENT] = saturate(unsat, self._ilo, self._ihi)
        v[:, ns + IN_TARGET] = r
        if isinstance(load, np.ndarray) or load:
            v[:, ns + IN_LOAD] = load
        vin = v[:, :ns + 3]
        out = vin @ self._MT if self._MT.ndim == 2 else np.matmul(vin[:, None, :], self._MT)[:, 0, :]
        if self.form == "positional":
            e = self._ks * (r - v[:, self._lay.ring0])
            frozen = clamped(unsat, e, self._ilo, self._ihi)
            if frozen.any():     # the error sum (and the cached PID term after it) without this error
                acc = self._lay.pid0 + ACC
                out[:, acc] -= np.where(frozen, e, 0.0)
                if self._cached_u:
                    out[:, self._iu] -= np.where(frozen, self._g[0, acc] * e, 0.0)
        return out

    def _targets(self, target) -> np.ndarray:
        return clip_targets(target, self.n, self._rmax)
