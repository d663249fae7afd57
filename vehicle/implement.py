"""The spreader: working width, sections, metering shaft and the delay from shaft to ground.

Metering: each revolution of the metering shaft delivers ``kg_per_rev``; the hydraulic motor drives
the shaft through ``transmission_ratio`` (shaft rpm = motor rpm x ratio; the paper uses 0.2). To
apply ``rate`` kg/ha over ``width`` m at ``speed`` m/s the shaft must turn at
``rate * speed * width / 10 000 / kg_per_rev * 60`` rpm. Product metered at time t reaches the ground
``delivery_delay_s`` later, where the implement is by then.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from common.checks import check_number, check_positive
from common.errors import VehicleError

M2_PER_HA = 10_000.0


@dataclass(frozen=True)
class Implement:
    """A metered implement (all quantities SI except rpm and kg/ha).

    Attributes
    ----------
    width_m : float
        Working width, m.
    sections : int
        Number of equal sections across the width, switched on/off independently.
    kg_per_rev : float
        Metering constant: product per metering-shaft revolution, kg/rev.
    transmission_ratio : float
        Metering-shaft speed / hydraulic-motor speed (dimensionless).
    shaft_rpm_min, shaft_rpm_max : float
        Speed range of the metering shaft while applying, rpm.
    delivery_delay_s : float
        Time from the metering shaft to the ground, s.
    """

    width_m: float = 12.0
    sections: int = 6
    kg_per_rev: float = 0.5
    transmission_ratio: float = 0.2
    shaft_rpm_min: float = 5.0
    shaft_rpm_max: float = 150.0
    delivery_delay_s: float = 0.8

    def __post_init__(self):
        for name in ("width_m", "kg_per_rev", "transmission_ratio", "shaft_rpm_max"):
            check_positive(getattr(self, name), f"Implement: {name}", VehicleError)
        for name in ("shaft_rpm_min", "delivery_delay_s"):
            check_number(getattr(self, name), f"Implement: {name}", VehicleError, lo=0.0)
        if not isinstance(self.sections, (int, np.integer)) or isinstance(self.sections, bool) \
                or not 1 <= self.sections <= 128:
            raise VehicleError(f"Implement: sections must be an integer in [1, 128], got {self.sections!r}")
        if self.shaft_rpm_min >= self.shaft_rpm_max:
            raise VehicleError(f"Implement: shaft_rpm_min={self.shaft_rpm_min} must be below "
                               f"shaft_rpm_max={self.shaft_rpm_max}")
        if self.delivery_delay_s > 30:
            raise VehicleError(f"Implement: delivery_delay_s={self.delivery_delay_s} is not a delay "
                               "from a metering shaft to the ground (> 30 s)")

    # --- metering --------------------------------------------------------------------------------
    def target_shaft_rpm(self, rate_kg_ha, speed_m_s, width_m=None):
        """Shaft speed that applies ``rate_kg_ha`` at ``speed_m_s`` over ``width_m`` (default: full width).

        Vectorized; not clipped to the shaft's range (see `clip_shaft_rpm`). Returns rpm.
        """
        width = self.width_m if width_m is None else width_m
        rate, speed = np.asarray(rate_kg_ha, dtype=float), np.asarray(speed_m_s, dtype=float)
        return rate * speed * np.asarray(width, dtype=float) / M2_PER_HA / self.kg_per_rev * 60.0

    def clip_shaft_rpm(self, shaft_rpm):
        """Shaft speed held within [shaft_rpm_min, shaft_rpm_max]; zero (sections off) stays zero."""
        rpm = np.asarray(shaft_rpm, dtype=float)
        return np.where(rpm > 0, np.clip(rpm, self.shaft_rpm_min, self.shaft_rpm_max), 0.0)

    def mass_kg(self, shaft_rev):
        """Product metered by ``shaft_rev`` shaft revolutions, kg."""
        return np.asarray(shaft_rev, dtype=float) * self.kg_per_rev

    # --- sections --------------------------------------------------------------------------------
    @property
    def section_width_m(self) -> float:
        return self.width_m / self.sections

    @property
    def section_offsets_m(self) -> np.ndarray:
        """Lateral offset of each section's centre from the implement's centre, m, left positive,
        ordered left to right; shape (sections,)."""
        k = np.arange(self.sections)
        return self.width_m / 2 - self.section_width_m * (k + 0.5)

    def sections_on(self, polygon, x_m, y_m, heading_rad, implement_on=True):
        """Which sections apply: implement on and the section centre inside ``polygon``.

        Parameters
        ----------
        polygon : shapely geometry
            The field boundary in the same metric CRS as the positions.
        x_m, y_m, heading_rad : array_like, shape (n,)
            Implement reference point and heading (math convention) per tick.
        implement_on : bool or array_like of bool, shape (n,)

        Returns
        -------
        ndarray of bool, shape (n, sections)
        """
        x, y, h = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (x_m, y_m, heading_rad))
        off = self.section_offsets_m
        # Left of the heading (cos h, sin h) is (-sin h, cos h).
        sx = x[:, None] - np.sin(h)[:, None] * off
        sy = y[:, None] + np.cos(h)[:, None] * off
        inside = shapely.contains_xy(polygon, sx, sy)
        return inside & np.atleast_1d(np.asarray(implement_on, dtype=bool))[:, None]
