"""What to apply where the map has no rate (outside it, or on a nodata cell), as real controllers do."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common import MapError

MODES = ("off", "hold", "default")


@dataclass(frozen=True)
class RatePolicy:
    """The rate to apply when the lookup gives none.

    Parameters
    ----------
    mode : {"off", "hold", "default"}
        ``off``: apply 0 kg/ha. ``hold``: keep the last applied rate (0 if there is none yet).
        ``default``: apply `default_rate_kg_ha`.
    default_rate_kg_ha : float
        The rate for ``mode="default"``, kg/ha, >= 0.
    """

    mode: str = "off"
    default_rate_kg_ha: float = 0.0

    def __post_init__(self):
        if self.mode not in MODES:
            raise MapError(f"RatePolicy: mode={self.mode!r}; must be one of {', '.join(MODES)}")
        r = self.default_rate_kg_ha
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r) or r < 0:
            raise MapError(f"RatePolicy: default_rate_kg_ha={r!r} must be a finite rate >= 0 kg/ha")

    def apply(self, rate, inside, last=0.0):
        """The rate to command.

        Parameters
        ----------
        rate : float or ndarray
            The looked-up rate, kg/ha (NaN on nodata or outside).
        inside : bool or ndarray of bool
            Whether the point is on the map.
        last : float or ndarray
            The last commanded rate, kg/ha (for ``hold``; NaN or None counts as 0).

        Returns
        -------
        float or ndarray
            `rate` where it is known, else the policy's rate. Scalars in, a float out (~0.3 us).
        """
        if np.ndim(rate) == 0 and np.ndim(inside) == 0 and np.ndim(last) == 0:
            rate = float(rate)
            if inside and rate == rate:  # rate == rate: not NaN, without a call
                return rate
            return self._fallback(last)
        rate = np.asarray(rate, dtype=np.float64)
        known = np.asarray(inside, dtype=bool) & ~np.isnan(rate)
        if self.mode == "hold":
            fallback = np.nan_to_num(np.asarray(last if last is not None else 0.0, dtype=np.float64), nan=0.0)
        else:
            fallback = self._fallback(0.0)
        return np.where(known, rate, fallback)

    def _fallback(self, last) -> float:
        if self.mode == "off":
            return 0.0
        if self.mode == "default":
            return float(self.default_rate_kg_ha)
        return 0.0 if last is None or last != last else float(last)
