"""Kind ``ideal``: a reference meter whose shaft follows the target exactly (no plant, no delay).

Not a controller but a loop of its own: each period the shaft turns at exactly the (clipped) target,
so the product metered is exactly what the target asks for. Runs with it measure what is left when
metering is perfect: the geometry of landing, sections and the map (section control, issue #12,
separates geometry error from metering error this way). Its reported current is the static current
that would hold the target on the real plant (``target / shaft_rpm_per_a``, within the valve's
limits), for plots only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import ControllerError
from vrsim.controller.interface import LoopInfo, state_arrays
from vrsim.controller.loop_io import StepOutput, clip_targets, targets_matrix
from vrsim.controller.params import KindParams
from vrsim.controller.registry import register_loop


@dataclass(frozen=True)
class IdealParams(KindParams):
    """The ``ideal`` kind has no parameters."""

    KIND = "ideal"


class IdealLoop:
    """n reference meters: shaft speed = target, with no lag (the loop interface of `PlantLoop`)."""

    def __init__(self, info: LoopInfo, n: int = 1, record_fine: bool = False):
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ControllerError(f"n must be a positive integer, got {n!r}")
        self.info = info
        self.n = n
        self.control_period_s = info.control_period_s
        self.plant_step_s = info.plant_step_s
        self.n_fine = round(info.control_period_s / info.plant_step_s)
        self._record_fine = record_fine
        self._rev = np.zeros(n)

    def reset(self) -> None:
        """Back to rest."""
        self._rev = np.zeros(self.n)

    @property
    def state(self) -> dict:
        """Total shaft revolutions since rest (all an ideal meter remembers)."""
        return {"shaft_rev_total": self._rev.copy()}

    def set_state(self, state: dict) -> None:
        """Restore a state obtained from `state`."""
        self._rev = state_arrays(state, {"shaft_rev_total": (self.n,)}, "ideal loop")["shaft_rev_total"]

    @property
    def motor_angle_rad(self) -> np.ndarray:
        """Total motor angle since rest [rad], shape (n,)."""
        return self._rev * 2.0 * np.pi / self.info.plant.transmission_ratio

    def step(self, target_shaft_rpm, load_torque_nm=0.0) -> StepOutput:
        """One period at exactly the target (load torque has no effect)."""
        return self._periods(clip_targets(target_shaft_rpm, self.n, self.info.plant.shaft_rpm_max))

    def run(self, targets_rpm, load_torque_nm=0.0, context=None) -> StepOutput:
        """`step` once per row of `targets_rpm` ((K,) for n = 1, or (K, n)); outputs of shape (K, n),
        computed at once (nothing feeds back; the drive's `context` changes nothing)."""
        t = targets_matrix(targets_rpm, self.n)
        return self._periods(clip_targets(t.ravel(), t.size, self.info.plant.shaft_rpm_max).reshape(t.shape))

    def _periods(self, r: np.ndarray) -> StepOutput:
        """Outputs of periods with clipped targets `r` (shape (n,) or (K, n)); advances the revolutions."""
        p = self.info.plant
        rev = r * self.control_period_s / 60.0
        self._rev = self._rev + (rev if rev.ndim == 1 else rev.sum(axis=0))
        current = np.clip(r / p.shaft_rpm_per_a, p.current_min_a, p.current_max_a)
        return StepOutput(r.copy(), rev, current, r.copy())

    def step_fine(self, target_shaft_rpm, load_torque_nm=0.0) -> tuple[StepOutput, np.ndarray]:
        """`step`, plus the (constant) shaft speed at each plant step of the period, shape (n, N)."""
        if not self._record_fine:
            raise ControllerError("step_fine needs a loop built with record_fine=True")
        out = self.step(target_shaft_rpm, load_torque_nm)
        return out, np.repeat(out.shaft_rpm[:, None], self.n_fine, axis=1)


register_loop("ideal", IdealParams, "reference meter: the shaft follows the target exactly, no plant, "
              "no delay", loop=lambda params, info, n, record_fine: IdealLoop(info, n, record_fine))
