"""The spreader: working width, sections, metering shaft and the delay from shaft to ground.

Metering: each revolution of the metering shaft delivers ``kg_per_rev``; the hydraulic motor drives
the shaft through ``transmission_ratio`` (shaft rpm = motor rpm x ratio; the paper uses 0.2). To
apply ``rate`` kg/ha over ``width`` m at ``speed`` m/s the shaft must turn at
``rate * speed * width / 10 000 / kg_per_rev * 60`` rpm. Product metered at time t reaches the ground
``delivery_delay_s`` later, where the implement is by then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from vrsim.common.checks import check_number, check_positive
from vrsim.common.errors import VehicleError
from vrsim.vehicle.machines import DEFAULT_KIND, MachineSpec, spec_class

M2_PER_HA = 10_000.0
SECTION_CONTROL_MODES = ("coverage", "boundary", "off")  # the switching engines' registry keys
DEFAULT_SECTIONS = 6
MAX_SECTIONS = 128  # ISOBUS task controllers address at most this many sections per boom
MAX_SECTION_DELAY_S = 30.0
MAX_SECTION_MIN_SPEED_M_S = 5.0   # a section cutoff above a field's working speeds would never apply


@dataclass(frozen=True)
class Implement:
    """A metered implement (all quantities SI except rpm and kg/ha).

    Attributes
    ----------
    width_m : float
        Working width, m.
    sections : int or None
        Number of sections across the width, switched on/off independently (1 to 128). None: one
        per entry of `section_widths_m`, or 6 equal sections if that is not given either; filled in
        on construction, so it is always the count.
    section_widths_m : tuple of float or None
        Width of each section from left to right, m; they must add up to `width_m`. None: the
        width split into `sections` equal sections (it stays None then, so a changed `width_m`
        keeps equal sections; `section_widths` gives the widths either way).
    kg_per_rev : float
        Metering constant: product per metering-shaft revolution, kg/rev.
    transmission_ratio : float
        Metering-shaft speed / hydraulic-motor speed (dimensionless).
    shaft_rpm_min, shaft_rpm_max : float
        Speed range of the metering shaft while applying, rpm.
    delivery_delay_s : float
        Time from the metering shaft to the ground, s.
    section_control : str
        How sections switch while the implement works (`SECTION_CONTROL_MODES`): "coverage" (off
        over ground already treated or outside the field, as terminals do), "boundary" (a section
        applies while its centre lands inside the field, with no latency) or "off" (all sections on).
    section_overlap_pct : float
        Coverage control: a section switches off when more than this share of its strip would land
        on ground already treated, %, in [0, 100] (0: no overlap, skips instead; 100: no skips).
    boundary_overlap_pct : float
        Coverage control: ... or when more than this share would land outside the field, %.
    section_on_delay_s, section_off_delay_s : float
        Coverage control: time from a section's on (off) command until product starts (stops)
        leaving the meter at that section, s, in [0, 30]; the controller looks ahead by it plus
        the delivery delay. Defaults as John Deere's terminals (1.0 s on, 0.6 s off).
    section_min_speed_m_s : float
        Coverage control: a section switches off while its own ground speed (the sensed speed minus
        the yaw rate times its offset: the inner end of a tight turn pivots or moves backwards) is
        at most this, m/s, in [0, 5]; 0.14 m/s (0.5 km/h) as AgOpenGPS's slow speed cutoff.
    kind : str
        How the machine meters and where its product lands (`vehicle.machines`): "gated_meter" (one
        shaft, a gate per section; the default) or "section_drives" (a drive per section).
    machine : vehicle.machines.MachineSpec or None
        The kind's own keys (a scenario's ``[implement]`` holds them beside the shared ones). None:
        the kind's defaults; filled in on construction.
    """

    width_m: float = 12.0
    sections: int | None = None
    kg_per_rev: float = 0.5
    transmission_ratio: float = 0.2
    shaft_rpm_min: float = 5.0
    shaft_rpm_max: float = 150.0
    delivery_delay_s: float = 0.8
    section_widths_m: tuple[float, ...] | None = None
    section_control: str = "coverage"
    section_overlap_pct: float = 50.0
    boundary_overlap_pct: float = 50.0
    section_on_delay_s: float = 1.0
    section_off_delay_s: float = 0.6
    section_min_speed_m_s: float = 0.14
    kind: str = DEFAULT_KIND
    machine: MachineSpec | None = None

    def __post_init__(self):
        for name in ("width_m", "kg_per_rev", "transmission_ratio", "shaft_rpm_max"):
            check_positive(getattr(self, name), f"Implement: {name}", VehicleError)
        for name in ("shaft_rpm_min", "delivery_delay_s"):
            check_number(getattr(self, name), f"Implement: {name}", VehicleError, lo=0.0)
        self._resolve_sections()
        if self.section_control not in SECTION_CONTROL_MODES:
            raise VehicleError("Implement: section_control must be one of "
                               f"{', '.join(SECTION_CONTROL_MODES)}, got {self.section_control!r}")
        for name in ("section_overlap_pct", "boundary_overlap_pct"):
            check_number(getattr(self, name), f"Implement: {name}", VehicleError, lo=0.0, hi=100.0, unit="%")
        for name in ("section_on_delay_s", "section_off_delay_s"):
            check_number(getattr(self, name), f"Implement: {name}", VehicleError, lo=0.0,
                         hi=MAX_SECTION_DELAY_S, unit="s")
        check_number(self.section_min_speed_m_s, "Implement: section_min_speed_m_s", VehicleError, lo=0.0,
                     hi=MAX_SECTION_MIN_SPEED_M_S, unit="m/s")
        self._resolve_machine()
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

    def shaft_limited(self, target_shaft_rpm):
        """Where a target from `clip_shaft_rpm` sits on a bound of the shaft's range while applying:
        the map asked for a speed the shaft cannot turn at (or exactly its bound)."""
        rpm = np.asarray(target_shaft_rpm, dtype=float)
        return (rpm > 0) & ((rpm <= self.shaft_rpm_min) | (rpm >= self.shaft_rpm_max))

    def mass_kg(self, shaft_rev):
        """Product metered by ``shaft_rev`` shaft revolutions, kg."""
        return np.asarray(shaft_rev, dtype=float) * self.kg_per_rev

    def _resolve_machine(self):
        """Fill in `machine` with the kind's defaults if not given; check it is the kind's and that
        the kind supports this many sections."""
        spec = spec_class(self.kind)
        if self.machine is None:
            object.__setattr__(self, "machine", spec())
        elif type(self.machine) is not spec:
            raise VehicleError(f"Implement: machine {self.machine!r} is not of kind {self.kind!r} "
                               "(machine=None takes the kind's defaults)")
        self.machine.check_sections(self.sections)
        self.machine.check_width(self.width_m)

    # --- sections --------------------------------------------------------------------------------
    def _resolve_sections(self):
        """Fill in `sections` from whichever of it and `section_widths_m` was given, and check them."""
        count, widths = self.sections, self.section_widths_m
        if count is not None and (not isinstance(count, (int, np.integer)) or isinstance(count, bool)
                                  or not 1 <= count <= MAX_SECTIONS):
            raise VehicleError(f"Implement: sections must be an integer in [1, {MAX_SECTIONS}], "
                               f"got {count!r}")
        if widths is None:   # by default 6, or as many as the kind supports if fewer (a spinner's 2 sides)
            default = min(DEFAULT_SECTIONS, spec_class(self.kind).MAX_SECTIONS or DEFAULT_SECTIONS)
            object.__setattr__(self, "sections", default if count is None else int(count))
        else:
            widths = _section_widths(widths)
            if count is not None and count != len(widths):
                raise VehicleError(f"Implement: sections={count} but section_widths_m has {len(widths)} "
                                   f"widths {list(widths)!r}")
            if not math.isclose(sum(widths), self.width_m, rel_tol=1e-9, abs_tol=1e-6):
                raise VehicleError(f"Implement: section_widths_m {list(widths)!r} add up to "
                                   f"{sum(widths):g} m, not width_m={self.width_m!r}")
            # Frozen: the resolved values are set once here, so both fields always agree.
            object.__setattr__(self, "sections", len(widths))
            object.__setattr__(self, "section_widths_m", widths)

    @property
    def section_widths(self) -> np.ndarray:
        """Width of each section, m, left to right; shape (sections,)."""
        if self.section_widths_m is None:
            return np.full(self.sections, self.width_m / self.sections)
        return np.array(self.section_widths_m, dtype=float)

    @property
    def section_width_m(self) -> float:
        """Mean section width, m (the width of each when they are equal)."""
        return self.width_m / self.sections

    @property
    def section_offsets_m(self) -> np.ndarray:
        """Lateral offset of each section's centre from the implement's centre, m, left positive,
        ordered left to right; shape (sections,)."""
        w = self.section_widths
        return self.width_m / 2 - (np.cumsum(w) - w / 2)

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


def _section_widths(widths) -> tuple[float, ...]:
    """`widths` as a tuple of positive finite floats (at most `MAX_SECTIONS`), or a `VehicleError`."""
    if not isinstance(widths, (list, tuple, np.ndarray)) or not 1 <= len(widths) <= MAX_SECTIONS:
        raise VehicleError(f"Implement: section_widths_m must be a list of 1 to {MAX_SECTIONS} widths, "
                           f"got {widths!r}")
    for i, w in enumerate(widths):
        check_positive(w, f"Implement: section_widths_m[{i}]", VehicleError)
    return tuple(float(w) for w in widths)
