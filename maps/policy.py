"""What to apply where the map has no rate (outside it, or on a nodata cell), as real controllers do."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common import MapError, check_number

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
        check_number(self.default_rate_kg_ha, "RatePolicy: default_rate_kg_ha", MapError, lo=0.0,
                     unit="kg/ha")

    def apply(self, rate, inside, last=0.0):
        """The rate to command, at one point or along a sequence of ticks.

        Parameters
        ----------
        rate : float or ndarray, shape (n,)
            The looked-up rate, kg/ha (NaN on nodata or outside); an array is a sequence of ticks in
            time order.
        inside : bool or ndarray of bool, shape (n,)
            Whether the point is on the map.
        last : float or None
            The rate commanded before (before the first tick of an array), kg/ha; for ``hold``.
            NaN or None counts as 0.

        Returns
        -------
        float or ndarray
            `rate` where it is known, else the policy's rate. With ``hold``, an unknown rate in an
            array takes the last known one before it in the array (else `last`), as tick-by-tick
            calls carrying `last` over would. Scalars in, a float out (~0.3 us).
        """
        if np.ndim(rate) == 0 and np.ndim(inside) == 0:
            rate = float(rate)
            if inside and rate == rate:  # rate == rate: not NaN, without a call
                return rate
            return self._fallback(last)
        rate = np.asarray(rate, dtype=np.float64)
        known = np.asarray(inside, dtype=bool) & ~np.isnan(rate)
        if self.mode != "hold":
            return np.where(known, rate, self._fallback(last))
        if rate.ndim != 1:
            raise MapError(f"RatePolicy: hold needs a 1-D sequence of ticks, got shape {rate.shape}")
        # Index of the last known rate at or before each tick (-1: none yet in this array).
        held = np.maximum.accumulate(np.where(known, np.arange(rate.size), -1))
        return np.where(held >= 0, rate[np.maximum(held, 0)], self._fallback(last))

    def _fallback(self, last) -> float:
        if self.mode == "off":
            return 0.0
        if self.mode == "default":
            return float(self.default_rate_kg_ha)
        return 0.0 if last is None or last != last else float(last)
