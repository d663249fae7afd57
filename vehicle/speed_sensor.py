"""The ground-speed sensor the rate controller reads: radar, wheel or perfect.

Model: the sensor samples the true speed at ``rate_hz`` and holds it; each sample reads
``v * (1 + bias + sigma * w)`` with ``w`` seeded standard normal noise. A radar is unbiased with about
1 % noise; a wheel sensor over-reads by the wheel slip (about 3 %) with less noise. `SpeedSensor.measure`
(a whole track) and `SpeedSensor.read` (one tick) give identical numbers for the same seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vrsim.common.checks import check_number
from vrsim.common.errors import VehicleError
from vrsim.vehicle.track import track_arrays

# (noise 1-sigma, bias) in percent of the true speed, the unit of `noise_pct` and `bias_pct`: a class's
# value and the same value written as an override are the same number (x / 100 rounds alike).
CLASSES = {"perfect": (0.0, 0.0), "radar": (1.0, 0.0), "wheel": (0.5, 3.0)}


@dataclass(frozen=True)
class SpeedSensorConfig:
    """A speed sensor.

    Attributes
    ----------
    kind : str
        "radar", "wheel" or "perfect".
    rate_hz : float
        Sample rate, Hz.
    noise_pct, bias_pct : float, optional
        Override the class's 1-sigma noise and bias, percent of the true speed; None: the class's
        (`CLASSES`; `resolved` fills them in).
    """

    kind: str = "radar"
    rate_hz: float = 10.0
    noise_pct: float | None = None
    bias_pct: float | None = None

    def __post_init__(self):
        if self.kind not in CLASSES:
            raise VehicleError(f"SpeedSensorConfig: kind must be one of {', '.join(CLASSES)}, "
                               f"got {self.kind!r}")
        checks = [("rate_hz", self.rate_hz, 0.0, 1000.0, True)]
        if self.noise_pct is not None:
            checks.append(("noise_pct", self.noise_pct, 0.0, 50.0, False))
        if self.bias_pct is not None:
            checks.append(("bias_pct", self.bias_pct, -50.0, 50.0, False))
        for name, value, lo, hi, open_lo in checks:
            check_number(value, f"SpeedSensorConfig: {name}", VehicleError, lo=lo, hi=hi, lo_open=open_lo)

    @property
    def sigma(self) -> float:
        """The 1-sigma noise used, a fraction of the true speed."""
        return (CLASSES[self.kind][0] if self.noise_pct is None else self.noise_pct) / 100.0

    @property
    def bias(self) -> float:
        """The bias used, a fraction of the true speed."""
        return (CLASSES[self.kind][1] if self.bias_pct is None else self.bias_pct) / 100.0

    def resolved(self) -> SpeedSensorConfig:
        """A copy with `noise_pct` and `bias_pct` set to the values used (the class's where unset):
        the same sensor, its numbers shown."""
        kind_noise_pct, kind_bias_pct = CLASSES[self.kind]
        return replace(self, noise_pct=kind_noise_pct if self.noise_pct is None else self.noise_pct,
                       bias_pct=kind_bias_pct if self.bias_pct is None else self.bias_pct)


class SpeedSensor:
    """A seeded `SpeedSensorConfig` sensor."""

    def __init__(self, config: SpeedSensorConfig | None = None, seed: int = 1):
        self.config = config or SpeedSensorConfig()
        if not isinstance(self.config, SpeedSensorConfig):
            raise VehicleError("SpeedSensor: config must be a SpeedSensorConfig, "
                               f"got {type(config).__name__}")
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise VehicleError(f"SpeedSensor: seed must be an integer >= 0, got {seed!r}")
        self.seed = int(seed)
        self.reset()

    def reset(self) -> None:
        """Start a new track from the same seed."""
        self._rng = np.random.default_rng(self.seed)
        self._t0 = None
        self._j = -1
        self._value = 0.0

    def _sample_index(self, t, floor=np.floor):
        return floor((t - self._t0) * self.config.rate_hz + 1e-9)

    def measure(self, time_s, speed_m_s) -> np.ndarray:
        """Measured speed (m/s) for a whole track of increasing ``time_s`` (s); starts a new track."""
        self.reset()
        return self.measure_next(time_s, speed_m_s)

    def measure_next(self, time_s, speed_m_s) -> np.ndarray:
        """Measured speed (m/s) for the next ticks of the track begun by `measure` (or `read`): a track
        measured in parts equals the track measured whole, bit for bit."""
        t, v = track_arrays("SpeedSensor.measure", time_s, speed_m_s=speed_m_s)
        if self._t0 is None:
            self._t0 = t[0]
        j = self._sample_index(t).astype(int)
        # One draw per sample since the last one taken, skipped samples included (as `read` draws).
        w = self._rng.standard_normal(max(j[-1] - self._j, 0))
        first = np.concatenate([[j[0] != self._j], j[1:] != j[:-1]])  # the tick at which each sample is taken
        sampled = v[first] * (1.0 + self.config.bias + self.config.sigma * w[j[first] - self._j - 1])
        held = np.concatenate([[self._value], sampled])  # ticks before the part's first sample hold the last
        self._j, self._value = int(j[-1]), float(held[-1])
        return held[np.cumsum(first)]

    def read(self, time_s: float, speed_m_s: float) -> float:
        """Measured speed (m/s) at one tick; call with increasing ``time_s``."""
        t = float(time_s)
        if self._t0 is None:
            self._t0 = t
        j = int(self._sample_index(t, math.floor))
        if j > self._j:
            w = self._rng.standard_normal(j - self._j)[-1]  # samples skipped between ticks draw too
            self._value = float(speed_m_s * (1.0 + self.config.bias + self.config.sigma * w))
            self._j = j
        return self._value
