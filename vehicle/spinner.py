"""The twin-disc spinner spreader: its own keys and its transverse spread pattern.

A spinner throws granular product off two discs across a spread width wider than the driving width
(``[implement] width_m``), so that neighbouring passes overlap by design. Its pattern is the
*transverse pattern*: relative mass per metre of lateral offset from the machine's centre line
(positive to the left of travel, as `maps.Strips` measures across). The left disc throws the part
left of the centre line, the right disc the part right of it; the two halves make the machine's
pattern (equal disc rates). Product lands ``throw_distance_m`` behind the discs.

Shapes (``pattern``):

- ``"triangular"``: mass falls linearly from the centre line to zero at half the spread width;
- ``"trapezoidal"``: flat over the central half of the spread width, falling linearly to zero over
  each outer quarter (the shape assumed here for a trapezoid: `TRAPEZOID_TOP_SHARE`);
- a path to a CSV of a measured catch-tray profile (relative to the scenario's folder), one row per
  tray: lateral offset (m, increasing, positive to the left), relative mass (>= 0), at most
  `MAX_PROFILE_ROWS` rows (read line by line, refused past it). An optional first row of column
  names and lines starting with ``#`` are skipped. The profile is linear between the trays' offsets
  and zero beyond the first and the last; it must lie within half the spread width on each side and
  put mass on both sides of the centre line (each disc throws one half).

At the field boundary (`SpinnerSpec.side_reach_m`): with ``border_spreading`` the side towards the
boundary is cut at the boundary itself, so product stays inside; without it, section control shortens
the side's reach (the lateral extent of its half, m) in ``side_steps`` equal steps, a step switched off
once it lies wholly beyond the boundary (what a partly outside step throws lands outside). Over ground
already treated, coverage section control shortens each side's reach in the same ``side_steps`` steps
(`services.sim.sections.SectionSwitch`), with or without border spreading.

`SpinnerSpec` is the machine kind ``spinner``'s keys (`vehicle.machines`): at most 2 sections (the
two sides), a spread width at least the driving width, a profile CSV's path resolved against the
scenario's folder (`SpinnerSpec.resolved`).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from vrsim.common import files
from vrsim.common.checks import check_number, check_positive
from vrsim.common.errors import VehicleError
from vrsim.common.pattern_integral import cumulative_mass
from vrsim.vehicle.machines import MachineSpec, register_spec

PATTERN_SHAPES = ("triangular", "trapezoidal")
TRAPEZOID_TOP_SHARE = 0.5  # a trapezoid's flat top spans this share of the spread width
MIN_PROFILE_ROWS = 3
MAX_PROFILE_ROWS = 10_000  # a catch-tray test lays tens to hundreds of trays; checked while reading
MAX_PROFILE_LINE = 256  # characters of one row (two numbers)
MAX_SIDE_STEPS = 16
MAX_THROW_DISTANCE_M = 100.0


@register_spec
@dataclass(frozen=True)
class SpinnerSpec(MachineSpec):
    """A spinner spreader's own ``[implement]`` keys (SI units): the machine kind ``spinner``.

    Attributes
    ----------
    spread_width_m : float
        Width the discs throw product over, m (at least the driving width ``width_m``).
    pattern : str
        ``"triangular"``, ``"trapezoidal"`` or a path to a catch-tray profile CSV (module docstring).
    throw_distance_m : float
        How far behind the discs the product lands, m, in [0, 100].
    border_spreading : bool
        At the field boundary the outer side's pattern is cut at the boundary, so product stays inside.
    side_steps : int
        Section control: each side's reach is shortened in this many equal steps (1 to 16; 1: the side
        only on or off): over treated ground (coverage section control) and, without
        `border_spreading`, at the field boundary.
    """

    KIND: ClassVar[str] = "spinner"
    MAX_SECTIONS: ClassVar[int | None] = 2   # the two sides (discs), switched apart

    spread_width_m: float = 36.0
    pattern: str = "triangular"
    throw_distance_m: float = 8.0
    border_spreading: bool = True
    side_steps: int = 4

    def __post_init__(self):
        check_positive(self.spread_width_m, "SpinnerSpec: spread_width_m", VehicleError, unit="m")
        check_number(self.throw_distance_m, "SpinnerSpec: throw_distance_m", VehicleError, lo=0.0,
                     hi=MAX_THROW_DISTANCE_M, unit="m")
        if not isinstance(self.border_spreading, bool):
            raise VehicleError("SpinnerSpec: border_spreading must be true or false, "
                               f"got {self.border_spreading!r}")
        steps = self.side_steps
        if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= MAX_SIDE_STEPS:
            raise VehicleError(f"SpinnerSpec: side_steps must be an integer in [1, {MAX_SIDE_STEPS}], "
                               f"got {steps!r}")
        if not isinstance(self.pattern, str) or not self.pattern.strip():
            raise VehicleError(f"SpinnerSpec: pattern must be one of {', '.join(PATTERN_SHAPES)} or a CSV "
                               f"file's path, got {self.pattern!r}")

    @property
    def half_width_m(self) -> float:
        """Half the spread width: the full reach of each side, m."""
        return self.spread_width_m / 2.0

    def check_width(self, width_m: float) -> None:
        """Refuse a spread width narrower than the driving width `width_m` (m): passes would not meet."""
        if self.spread_width_m < width_m:
            raise VehicleError(f"SpinnerSpec: spread_width_m={self.spread_width_m:g} must be at least the "
                               f"driving width width_m={width_m:g}")

    def resolved(self, base_dir: str) -> SpinnerSpec:
        """The spec with a profile CSV's path made absolute against `base_dir` (the scenario's folder)
        and the profile read and checked (`VehicleError` naming file, row and value)."""
        if self.pattern in PATTERN_SHAPES:
            return self
        _check_csv_name(self.pattern)
        path = os.path.abspath(os.path.join(base_dir, os.path.expanduser(self.pattern)))
        spec = dataclasses.replace(self, pattern=path)
        spec.transverse_pattern()
        return spec

    def transverse_pattern(self) -> TransversePattern:
        """The machine's transverse pattern: a shape's, or the profile CSV's (`resolved`: relative
        paths are relative to the working folder here), checked against the spread width."""
        h = self.half_width_m
        if self.pattern == "triangular":
            return TransversePattern.normalized([-h, 0.0, h], [0.0, 1.0, 0.0], self.pattern)
        if self.pattern == "trapezoidal":
            top = h * TRAPEZOID_TOP_SHARE
            return TransversePattern.normalized([-h, -top, top, h], [0.0, 1.0, 1.0, 0.0], self.pattern)
        path = os.path.expanduser(_check_csv_name(self.pattern))
        offset, mass = _read_profile_csv(path, h)
        return TransversePattern.normalized(offset, mass, path)

    def side_reach_m(self, room_m) -> np.ndarray:
        """The reach a side is set to, m, given the lateral room it has to the field boundary (m, from
        its disc's centre line; vectorized; inf: no boundary within reach, <= 0: the disc's product
        would land outside): with `border_spreading` the room itself (cut at the boundary), up to half
        the spread width; without it, the `side_steps` reach whose outermost step is the one the
        boundary crosses (a step switched off once wholly outside the field; 0: the side off)."""
        h = self.half_width_m
        room = np.clip(np.asarray(room_m, dtype=float), 0.0, h)
        if self.border_spreading:
            return room
        return h * np.ceil(room / h * self.side_steps - 1e-9) / self.side_steps




@dataclass(frozen=True)
class TransversePattern:
    """A spinner's transverse pattern: relative mass per metre at lateral offsets, linear between the
    knots and zero beyond them; normalized so the whole pattern holds 1 (each disc's half: its share).

    Attributes
    ----------
    offset_m : ndarray, shape (n,)
        Knots' lateral offsets, m, increasing (positive: left of travel).
    mass_per_m : ndarray, shape (n,)
        Relative mass per metre at each knot, 1/m (>= 0).
    source : str
        The shape's name or the profile file's path.
    """

    offset_m: np.ndarray
    mass_per_m: np.ndarray
    source: str

    @classmethod
    def normalized(cls, offset_m, mass, source: str) -> TransversePattern:
        """The pattern of knots (`offset_m`, relative `mass`) scaled to hold 1 in all."""
        offset, mass = np.asarray(offset_m, dtype=float), np.asarray(mass, dtype=float)
        return cls(offset, mass / np.trapezoid(mass, offset), source)

    def density(self, offset_m) -> np.ndarray:
        """Relative mass per metre at `offset_m` (m, vectorized), 1/m; zero beyond the knots."""
        return np.interp(offset_m, self.offset_m, self.mass_per_m, left=0.0, right=0.0)

    def cumulative(self, offset_m) -> np.ndarray:
        """The pattern's mass from its right end up to `offset_m` (m, vectorized): exact for its
        piecewise-linear density (`common.pattern_integral.cumulative_mass`)."""
        return cumulative_mass(self.offset_m, self.mass_per_m, offset_m)

    def side_share(self, side, reach_m) -> np.ndarray:
        """The share of one side's mass (`side` +1: left of the centre line, -1: right) that lies
        within `reach_m` (m) of the centre line (vectorized): what a side cut to that reach throws."""
        side = np.asarray(side, dtype=float)
        whole = np.abs(self.cumulative(side * np.inf) - self.cumulative(0.0))
        return np.abs(self.cumulative(side * np.asarray(reach_m, float)) - self.cumulative(0.0)) / whole

    def side_centre_m(self, side: int) -> float:
        """Where the centre of one side's mass lies across (m, signed: left positive), the point the
        side's rate is looked up at."""
        x = np.linspace(0.0, side * max(abs(self.offset_m[0]), abs(self.offset_m[-1])), 2001)
        mass = self.density(x)
        return float(np.trapezoid(x * mass, x) / np.trapezoid(mass, x))

    @property
    def extent_m(self) -> tuple[float, float]:
        """How far the pattern reaches right (<= 0) and left (>= 0) of the centre line, m."""
        return min(float(self.offset_m[0]), 0.0), max(float(self.offset_m[-1]), 0.0)


def _read_profile_csv(path: str, half_width_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A catch-tray profile's (offsets m, relative masses) from a CSV (module docstring), checked:
    at least `MIN_PROFILE_ROWS` rows of two numbers, offsets increasing and within `half_width_m`
    (m) of the centre line, masses >= 0, not all zero, some on each side of the centre line.

    Raises
    ------
    VehicleError
        ``"pattern FILE: row N: ..."`` naming the row (the file's line) and the value.
    """
    rows = _profile_rows(path)
    if not rows:
        raise VehicleError(f"pattern {path}: no rows (a catch-tray profile: lateral offset m, relative mass)")
    values = np.array([_row_values(path, n, line) for n, line in rows])
    lines = [n for n, _ in rows]
    offset, mass = values[:, 0], values[:, 1]
    if len(rows) < MIN_PROFILE_ROWS:
        raise VehicleError(f"pattern {path}: {len(rows)} row(s): a profile needs at least {MIN_PROFILE_ROWS}")
    negative = np.flatnonzero(mass < 0)
    if negative.size:
        i = negative[0]
        raise VehicleError(f"pattern {path}: row {lines[i]}: relative mass {mass[i]:g} is negative")
    unsorted = np.flatnonzero(np.diff(offset) <= 0)
    if unsorted.size:
        i = unsorted[0] + 1
        raise VehicleError(f"pattern {path}: row {lines[i]}: offset {offset[i]:g} m does not increase "
                           f"(previous row: {offset[i - 1]:g} m)")
    if not mass.any():
        raise VehicleError(f"pattern {path}: every relative mass is zero: no product is thrown")
    beyond = np.flatnonzero(np.abs(offset) > half_width_m * (1 + 1e-9))
    if beyond.size:
        i = beyond[0]
        raise VehicleError(f"pattern {path}: row {lines[i]}: offset {offset[i]:g} m lies beyond half the "
                           f"spread width ({half_width_m:g} m): widen spread_width_m or cut the profile")
    for name, side in (("left", offset > 0), ("right", offset < 0)):
        if not (mass[side] > 0).any():
            raise VehicleError(f"pattern {path}: no mass {name} of the centre line: each disc throws one "
                               "half of the profile")
    return offset, mass


def _profile_rows(path: str) -> list[tuple[int, str]]:
    """The profile's rows as (line number, text), column names and comments left out, read line by
    line and refused past `MAX_PROFILE_ROWS` rows or a row of over `MAX_PROFILE_LINE` characters."""
    try:
        fh = files.open_text(path, "csv", VehicleError, encoding="utf-8-sig")  # a regular file, in its cap
    except VehicleError as exc:
        raise VehicleError(f"pattern {exc}") from None
    try:
        with fh:
            return _capped_rows(path, iter(lambda: fh.readline(MAX_PROFILE_LINE + 1), ""))
    except UnicodeDecodeError as exc:
        raise VehicleError(f"pattern {path}: not a text file: {exc}") from None
    except OSError as exc:
        raise VehicleError(f"pattern {path}: cannot read: {exc.strerror}") from None


def _capped_rows(path: str, lines) -> list[tuple[int, str]]:
    rows: list[tuple[int, str]] = []
    first = True  # the first row may be column names
    for n, line in enumerate(lines, start=1):
        if len(line.rstrip("\r\n")) > MAX_PROFILE_LINE:
            raise VehicleError(f"pattern {path}: row {n}: over {MAX_PROFILE_LINE} characters (a row is two "
                               "numbers: lateral offset m, relative mass)")
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if first and not _numeric(line.split(",")[0]):
            first = False
            continue
        if len(rows) == MAX_PROFILE_ROWS:
            raise VehicleError(f"pattern {path}: over {MAX_PROFILE_ROWS:,} rows; a catch-tray profile has "
                               "tens to hundreds of trays")
        first = False
        rows.append((n, line))
    return rows


def _check_csv_name(pattern: str) -> str:
    """`pattern` if it names a CSV file; `VehicleError` naming the shapes otherwise."""
    if not os.path.splitext(pattern)[1].lower() == ".csv":
        raise VehicleError(f"SpinnerSpec: pattern must be one of {', '.join(PATTERN_SHAPES)} or a CSV "
                           f"file's path (.csv), got {pattern!r}")
    return pattern


def _numeric(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _row_values(path: str, n: int, line: str) -> tuple[float, float]:
    """A row's (offset, mass); `VehicleError` for a row that is not two finite numbers."""
    cells = [c.strip() for c in line.split(",")]
    if len(cells) != 2:
        raise VehicleError(f"pattern {path}: row {n}: {line!r} has {len(cells)} field(s), expected 2 "
                           "(lateral offset m, relative mass)")
    for cell in cells:
        if not _numeric(cell) or not np.isfinite(float(cell)):
            raise VehicleError(f"pattern {path}: row {n}: {cell!r} is not a finite number")
    return float(cells[0]), float(cells[1])

