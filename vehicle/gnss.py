"""A GNSS receiver: seeded, time-correlated position error, sample and hold at the update rate, latency.

Error model: each horizontal axis carries a first-order Gauss-Markov error
``e[j] = a e[j-1] + sigma sqrt(1 - a^2) w[j]``, ``a = exp(-1 / (rate_hz tau_s))``, started in its
stationary distribution, one value per fix. Fix ``j`` samples the true position at
``t_j = t0 + j / rate_hz`` (``t0``: the first time seen) and is output from ``t_j + latency_s`` until
the next fix replaces it; before the first fix is due the receiver outputs fix 0.

`Gnss.measure` does a whole track at once; `Gnss.fix` does one tick at a time for the services.
Both interpolate the true position at ``t_j`` linearly between the two ticks around it and draw the
same random numbers in the same order, so they give identical numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from itertools import chain

import numpy as np

from vrsim.common.checks import check_number
from vrsim.common.errors import VehicleError
from vrsim.vehicle.track import track_arrays

# Per-axis 1-sigma horizontal error (m) and correlation time (s) of each receiver class.
CLASSES = {
    "perfect": (0.0, 1.0),
    "rtk": (0.02, 10.0),
    "dgps": (0.3, 60.0),
    "autonomous": (1.5, 300.0),
}


@dataclass(frozen=True)
class GnssConfig:
    """A receiver.

    Attributes
    ----------
    kind : str
        "rtk" (~0.02 m), "dgps" (~0.3 m), "autonomous" (~1.5 m) or "perfect".
    rate_hz : float
        Fix rate, Hz.
    latency_s : float
        Delay from sampling a fix to its output, s.
    sigma_m, tau_s : float, optional
        Override the class's per-axis standard deviation (m) and correlation time (s); None: the
        class's (`CLASSES`; `resolved` fills them in).
    """

    kind: str = "rtk"
    rate_hz: float = 10.0
    latency_s: float = 0.1
    sigma_m: float | None = None
    tau_s: float | None = None

    def __post_init__(self):
        if self.kind not in CLASSES:
            raise VehicleError(f"GnssConfig: kind must be one of {', '.join(CLASSES)}, got {self.kind!r}")
        _positive("rate_hz", self.rate_hz, hi=100.0)
        _positive("latency_s", self.latency_s, allow_zero=True, hi=10.0)
        if self.sigma_m is not None:
            _positive("sigma_m", self.sigma_m, allow_zero=True, hi=100.0)
        if self.tau_s is not None:
            _positive("tau_s", self.tau_s)

    @property
    def sigma(self) -> float:
        """The per-axis 1-sigma error the receiver uses [m]."""
        return CLASSES[self.kind][0] if self.sigma_m is None else float(self.sigma_m)

    @property
    def tau(self) -> float:
        """The error's correlation time the receiver uses [s]."""
        return CLASSES[self.kind][1] if self.tau_s is None else float(self.tau_s)

    def resolved(self) -> GnssConfig:
        """A copy with `sigma_m` and `tau_s` set to the values used (the class's where unset): the
        same receiver, its numbers shown."""
        return replace(self, sigma_m=self.sigma, tau_s=self.tau)


def _positive(name, value, allow_zero=False, hi=None):
    check_number(value, f"GnssConfig: {name}", VehicleError, lo=0.0, hi=hi, lo_open=not allow_zero)


class Gnss:
    """A seeded receiver of `GnssConfig` (see the module docstring for the model).

    Parameters
    ----------
    config : GnssConfig
    seed : int
    """

    def __init__(self, config: GnssConfig | None = None, seed: int = 1):
        self.config = config or GnssConfig()
        if not isinstance(self.config, GnssConfig):
            raise VehicleError(f"Gnss: config must be a GnssConfig, got {type(config).__name__}")
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise VehicleError(f"Gnss: seed must be an integer >= 0, got {seed!r}")
        self.seed = int(seed)
        self.period_s = 1.0 / self.config.rate_hz
        self._a = math.exp(-self.period_s / self.config.tau)
        self._b = self.config.sigma * math.sqrt(1.0 - self._a ** 2)
        self.reset()

    def reset(self) -> None:
        """Forget the track: the next `fix` starts a new one from the same seed."""
        self._rng = np.random.default_rng(self.seed)
        self._t0 = None
        self._prev = None        # (t, x, y) of the previous tick
        self._fixes = []         # (x, y) of each fix sampled so far and still due (from fix `_dropped` on)
        self._dropped = 0        # fixes no tick will be given again (a long drive keeps only recent ones)
        self._err = None         # current (ex, ey)

    # --- shared pieces ---------------------------------------------------------------------------
    def _errors(self, n: int, start=None) -> np.ndarray:
        """Next ``n`` Gauss-Markov errors, shape (n, 2), continuing from ``start`` (or stationary)."""
        w = self._rng.standard_normal((n, 2))
        first = w[0] * self.config.sigma if start is None else self._a * start + self._b * w[0]
        if n == 1:
            return first[None, :]
        # e[j] = a e[j-1] + b w[j], the per-tick recursion's very operations (bit for bit). Fixes
        # come at rate_hz, not per tick (~9,000 in a 22 ha run), so a plain loop costs milliseconds
        # and spares importing scipy.signal (~0.5-1 s) for a first-order filter.
        # Each axis on its own in a comprehension: a third of the time of one loop writing both into
        # an array, the same operations.
        a, b = self._a, self._b
        ex, ey = float(first[0]), float(first[1])
        rest_x = [ex := a * ex + b * wx for wx in w[1:, 0].tolist()]
        rest_y = [ey := a * ey + b * wy for wy in w[1:, 1].tolist()]
        return np.concatenate([first[None, :], np.column_stack([rest_x, rest_y])])

    def _fix_count(self, t, floor=np.floor):
        """How many fixes have been sampled by time ``t`` (array; scalar with ``floor=math.floor``)."""
        return floor((t - self._t0) * self.config.rate_hz + 1e-9) + 1

    def _due_index(self, t, floor=np.floor):
        """Index of the newest fix whose output time has come at ``t`` (negative: fix 0 is used)."""
        return floor((t - self._t0 - self.config.latency_s) * self.config.rate_hz + 1e-9)

    # --- vectorized ------------------------------------------------------------------------------
    def measure(self, time_s, x_m, y_m):
        """Measured positions for a whole track (starts a new track; identical to calling `fix`).

        Parameters
        ----------
        time_s, x_m, y_m : array_like, shape (n,)
            Strictly increasing tick times (s) and true positions (m).

        Returns
        -------
        x_meas_m, y_meas_m : ndarray, shape (n,)
        """
        self.reset()
        return self.measure_next(time_s, x_m, y_m)

    def measure_next(self, time_s, x_m, y_m):
        """Measured positions for the next ticks of the track begun by `measure` (or by `fix`): a track
        measured in parts equals the track measured whole, bit for bit (a streamed run measures each
        part as SUMO drives it).

        Parameters
        ----------
        time_s, x_m, y_m : array_like, shape (n,)
            Tick times (s), strictly increasing and after the ticks measured so far, and true
            positions (m).

        Returns
        -------
        x_meas_m, y_meas_m : ndarray, shape (n,)
        """
        t, x, y = track_arrays("Gnss.measure", time_s, x_m=x_m, y_m=y_m)
        if self._t0 is None:
            self._t0 = t[0]
            have, head = 0, 0
        else:  # the last tick measured joins the part: fixes fall between it and the part's first
            t_prev, x_prev, y_prev = self._prev
            if not t[0] > t_prev:
                raise VehicleError(f"Gnss.measure_next: time_s must increase, got {t[0]!r} after {t_prev!r}")
            t, x, y = (np.concatenate([[p], a]) for p, a in ((t_prev, t), (x_prev, x), (y_prev, y)))
            have, head = self._dropped + len(self._fixes), 1
        count = self._fix_count(t)  # fixes sampled once tick i is reached
        j = np.arange(have, int(count[-1]))
        tj = self._t0 + j * self.period_s
        # Fix j is sampled at the first tick i whose count exceeds j, between ticks i-1 and i.
        i = np.searchsorted(count, j + 1, side="left")
        im = np.maximum(i - 1, 0)
        f = np.divide(tj - t[im], t[i] - t[im], out=np.zeros(j.size), where=i > 0)
        fx = x[im] + (x[i] - x[im]) * f
        fy = y[im] + (y[i] - y[im]) * f
        if have == 0:
            fx[0], fy[0] = x[0], y[0]
        if j.size:
            e = self._errors(j.size, self._err)
            self._err = e[-1]
            self._fixes.extend(zip((fx + e[:, 0]).tolist(), (fy + e[:, 1]).tolist(), strict=True))
        self._prev = (float(t[-1]), float(x[-1]), float(y[-1]))
        due = np.maximum(self._due_index(t[head:]), 0).astype(int)
        first = int(due[0])  # the part's ticks output only fixes from there on (not all since t0)
        due_fixes = self._fixes[first - self._dropped:]   # (x, y) pairs: read flat, not tuple by tuple
        fixes = np.fromiter(chain.from_iterable(due_fixes), float, 2 * len(due_fixes)).reshape(-1, 2)
        del self._fixes[:first - self._dropped]   # the next part's ticks are due no earlier fix
        self._dropped = first
        return fixes[due - first, 0], fixes[due - first, 1]

    # --- per tick --------------------------------------------------------------------------------
    def fix(self, time_s: float, x_m: float, y_m: float):
        """Measured position at one tick (call with increasing ``time_s``); returns (x_m, y_m)."""
        t = float(time_s)
        if self._t0 is None:
            self._t0 = t
            self._prev = (t, float(x_m), float(y_m))
            self._sample(float(x_m), float(y_m))
        else:
            t_prev, x_prev, y_prev = self._prev
            if not t > t_prev:
                raise VehicleError(f"Gnss.fix: time_s must increase, got {t!r} after {t_prev!r}")
            while self._dropped + len(self._fixes) < self._fix_count(t, math.floor):  # fixes in (t_prev, t]
                tj = self._t0 + (self._dropped + len(self._fixes)) * self.period_s
                f = (tj - t_prev) / (t - t_prev)
                self._sample(x_prev + (x_m - x_prev) * f, y_prev + (y_m - y_prev) * f)
            self._prev = (t, float(x_m), float(y_m))
        j = max(self._due_index(t, math.floor), 0)
        return self._fixes[j - self._dropped]

    def _sample(self, x, y):
        self._err = self._errors(1, self._err)[0]
        self._fixes.append((float(x + self._err[0]), float(y + self._err[1])))
