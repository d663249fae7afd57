"""Where each section's product lands, and the overlap and skip figures that follow.

Product metered during tick [t, t + period] is shared between the sections whose gates are open
(`SectionStates.actual`) in proportion to their widths, and each share lands on its own section's
strip on the true path ``delivery_delay_s`` later: between where the section is at the start and
the end of that span. Consecutive ticks of one section are joined into strips up to half a map
cell long (their ends meet exactly; this blurs per-cell figures far below the cell size and cuts
the raster work many-fold); a strip ends where the section switches or the pass changes, so every
strip has one section, one pass and product all along.

The strips are the deposition engine's ``section_strips`` footprint (`maps.Strips`); with its pass
accounting (`maps.AsApplied`) and the plan's worked area (`worked_fraction`) they give the overlap
and skip figures (`services.sim.metrics.overlap_metrics`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vrsim.maps import AsApplied, ColumnDeposit, Grid, Strips
from vrsim.services.sim.sections import Poses, SectionStates, fill_outlines, runs_of

# The strips' API (`section_strips` for a run's strips with their masses, as the benchmarks and the
# tests call it; `StripPlan` for the plan the machine kinds deposit through; `tick_travel_m`,
# `WorkedArea`, `landing_frame` and `landing_pass` for a run accounted part by part).
__all__ = ["LimitedStrips", "SectionStrips", "StripPlan", "WorkedArea", "landing_frame", "landing_pass",
           "limited_coverage", "section_strips", "tick_travel_m", "worked_fraction"]

WORKED_SUPERSAMPLE = 4  # the worked area is counted at a quarter of a map cell ...
MAX_WORKED_CELLS = 16_000_000  # ... on at most this many fine cells (16 MB)


@dataclass(frozen=True)
class SectionStrips:
    """Strips of product, one entry per strip; arrays of shape (k,), in `AsApplied.add_strips`' terms."""

    x0_m: np.ndarray
    y0_m: np.ndarray
    x1_m: np.ndarray
    y1_m: np.ndarray
    width_m: np.ndarray
    mass_kg: np.ndarray
    pass_index: np.ndarray
    section: np.ndarray

    def footprint(self) -> Strips:
        """Where the strips put product: the deposition engine's ``section_strips`` footprint."""
        return Strips(self.x0_m, self.y0_m, self.x1_m, self.y1_m, self.width_m)

    def add_to(self, as_applied: AsApplied) -> None:
        """Accumulate the strips onto an as-applied raster, with their passes."""
        as_applied.deposit(self.footprint(), self.mass_kg, pass_index=self.pass_index)


def tick_travel_m(scenario) -> float:
    """A tick's travel at the scenario's working speed, m: how long the strips of its run's product are
    cut (`StripPlan.of`), known before anything is driven, so that a run accounted part by part
    (`services.sim.bounded`) cuts them as the whole run does."""
    return scenario.tractor.working_speed_m_s * scenario.timing.control_period_s


def section_strips(track: dict, metered_kg, states: SectionStates, delay_s: float, period_s: float,
                   cell_m: float, ticks=None, tick_m: float | None = None) -> SectionStrips:
    """Each section's product as strips on its own path, ordered by pass.

    Parameters
    ----------
    track : dict of ndarray, shape (n,)
        The true track (``time_s``, ``x_m``, ``y_m``, ``heading_rad``).
    metered_kg : ndarray, shape (n,)
        Product through the meter in each tick; 0 where all gates are closed (it stays in the
        hopper), else a `ValueError` (it would be lost).
    states : SectionStates
        Gate states per tick and section, section widths and offsets.
    delay_s, period_s : float
        Delivery delay and tick length, s.
    cell_m : float
        Map cell size: ticks are joined into strips up to half of it long.
    ticks : ndarray of int, optional
        Only these ticks (ascending indices), e.g. those metered at a clipped target; default all.
    tick_m : float, optional
        A tick's typical travel, m (`StripPlan.of`; a run's: `tick_travel_m`).
    """
    plan = StripPlan.of(track, states, delay_s, period_s, cell_m, ticks, tick_m)
    return dataclasses.replace(plan.strips, mass_kg=plan.mass_kg(metered_kg))


@dataclass(frozen=True)
class StripPlan:
    """Where each section's strips lie, before any product: the gates, passes and track decide the
    strips, the product only their masses, which are linear in the metered kg: a sparse map from ticks
    (and drives) to strips (each tick's product times its section's share), so one plan serves any
    number of controllers on one drive (`services.sim.variants`).

    One drive (the gated meter, ``own_drives=False``): a tick's product is shared between the open
    sections by width. A drive per section (``own_drives=True``): each section's strip carries its
    own drive's product."""

    strips: SectionStrips   # the geometry, passes and sections; mass_kg empty
    ticks: np.ndarray       # the ticks planned (indices into the track)
    width_on_m: np.ndarray  # (ticks,)
    to_strips: object       # scipy.sparse CSR (strips, ticks x drives): a section's share of a drive's kg
    drive_open: np.ndarray  # (ticks, drives): where each drive's product reaches the ground

    @classmethod
    def of(cls, track: dict, states: SectionStates, delay_s: float, period_s: float, cell_m: float,
           ticks=None, tick_m: float | None = None, first_tick: int = 0,
           own_drives: bool = False) -> StripPlan:
        """The plan of `section_strips` (same parameters, less the product); `own_drives`: a drive per
        section.

        `tick_m`: the typical tick's travel that sets how many ticks a strip joins (`_join_ticks`);
        None: the median over `ticks` (known only once they are all there). `first_tick`: the index
        in the whole run of the track's first tick, where a run is planned part by part
        (`services.sim.bounded`): strips end every `_join_ticks` ticks counted from the run's start."""
        time_s = np.asarray(track["time_s"], float)
        idx = np.arange(time_s.size) if ticks is None else np.asarray(ticks, np.int64)
        frame = landing_frame(track, delay_s, period_s, idx)
        passes = landing_pass(time_s, states.pass_index, delay_s, idx)
        # Tick numbers: a record with gaps (``track["tick"]``, the monitor's after it was down) breaks
        # there, as do ticks left out.
        numbers = np.asarray(track["tick"], np.int64)[idx] if "tick" in track else idx
        return cls.of_frame(frame, passes, states.actual[idx], numbers, states, cell_m, idx, tick_m,
                            first_tick, own_drives)

    @classmethod
    def of_frame(cls, frame: tuple, passes, actual, numbers, states: SectionStates, cell_m: float, idx,
                 tick_m: float | None = None, first_tick: int = 0, own_drives: bool = False) -> StripPlan:
        """`of` from the landing frames of its ticks (`landing_frame`: x0, y0, x1, y1, nx, ny), their
        landing passes, gates (ticks, sections) and tick numbers; `idx` the ticks' indices in the
        track. The section widths and offsets are `states`'."""
        from scipy import sparse

        n, sections = idx.size, actual.shape[1]
        x0, y0, x1, y1, nx, ny = frame
        width_on = actual @ states.widths_m
        on = actual.T   # section-major: each section's ticks in a row
        # Each open (section, tick)'s share of its drive's product, section-major as the strips are cut.
        if own_drives:
            drives, share, drive_open = sections, on.astype(float), actual
        else:
            drives, drive_open = 1, (width_on > 0)[:, None]
            share = np.divide(states.widths_m[:, None], width_on[None, :], out=np.zeros((sections, n)),
                              where=on & (width_on[None, :] > 0))
        if tick_m is None:
            tick_m = float(np.median(np.hypot(x1 - x0, y1 - y0))) if n else 0.0
        join = _join_ticks(cell_m, tick_m)
        # Groups along each section's ticks (section-major order), ending every `join` ticks, where the
        # section's gate changes, where the pass changes and where ticks are left out.
        brk = np.zeros((sections, n), bool)
        brk[:, (-first_tick) % join::join] = True
        brk[:, :1] = True   # each section's first tick (a run planned in parts: its part's first pass)
        brk[:, 1:] |= ((on[:, 1:] != on[:, :-1])
                       | ((passes[1:] != passes[:-1]) | (np.diff(numbers) > 1))[None, :])
        cuts = np.flatnonzero(brk.ravel())
        ends = np.append(cuts[1:], sections * n) - 1
        keep = on.ravel()[cuts]
        starts, ends = cuts[keep], ends[keep]
        per_section = max(n, 1)
        sec, first, last = starts // per_section, starts % per_section, ends % per_section
        off = states.offsets_m[sec]
        order = np.argsort(passes[first], kind="stable")  # by pass, each section's strips in time order
        strips = SectionStrips(x0[first] + nx[first] * off, y0[first] + ny[first] * off,
                               x1[last] + nx[last] * off, y1[last] + ny[last] * off,
                               states.widths_m[sec], np.zeros(0), passes[first], sec)
        strips = SectionStrips(*(getattr(strips, f) if f == "mass_kg" else getattr(strips, f)[order]
                                 for f in SectionStrips.__dataclass_fields__))
        # Each open (section, tick) goes to its group's strip (a group is all open or all closed, its
        # ticks consecutive in section-major order): the map's rows in the strips' order, each row's
        # ticks in time order (as a COO map converted would hold them).
        count = (ends - starts + 1)[order]
        flat = np.repeat(starts[order] - (np.cumsum(count) - count), count) + np.arange(count.sum())
        section, tick = np.divmod(flat, per_section)
        column = tick * drives + section if own_drives else tick   # one drive: the tick itself
        to_strips = sparse.csr_matrix((share.ravel()[flat], column, np.concatenate(([0], np.cumsum(count)))),
                                      shape=(order.size, n * drives))
        return cls(strips, idx, width_on, to_strips, drive_open)

    def footprint(self) -> Strips:
        """Where the strips put product (`SectionStrips.footprint`)."""
        return self.strips.footprint()

    @property
    def pass_index(self) -> np.ndarray:
        """The pass of each strip, shape (k,)."""
        return self.strips.pass_index

    def mass_kg(self, metered_kg) -> np.ndarray:
        """Product in each strip, kg, shape (k,) or (k, m): for one drive from `metered_kg` of shape
        (track ticks,) or (track ticks, m) (m controllers' columns), for several drives of shape
        (track ticks, drives) or (track ticks, drives, m); `ValueError` if a tick meters product where
        it cannot land (every gate closed; a drive's own section closed): it would be lost."""
        metered = np.asarray(metered_kg, float)
        every = len(self.ticks) == len(metered) and (not len(metered) or self.ticks[-1] == len(metered) - 1)
        if not every:   # (ascending ticks: as many as the track's, the last its last, are all of them)
            metered = metered[self.ticks]
        ticks, drives = self.drive_open.shape
        per_drive = metered.reshape(ticks, drives, -1) > 0
        lost = (per_drive & ~self.drive_open[:, :, None]).any(axis=(1, 2))
        if lost.any():
            closed = "every gate closed" if drives == 1 else "its section's gate closed"
            raise ValueError(f"section_strips: tick {int(self.ticks[np.argmax(lost)])} meters product with "
                             f"{closed}")
        columns = metered.shape[2:] if drives > 1 else metered.shape[1:]
        return np.asarray(self.to_strips @ metered.reshape(ticks * drives, *columns))


def limited_coverage(track: dict, metered_kg: np.ndarray, states: SectionStates, limited: np.ndarray,
                     delay_s: float, period_s: float, cell_m: float, grid: Grid) -> np.ndarray:
    """Share of each cell that product metered in `limited` ticks (the machine-limited ones) landed on,
    for each column of `metered_kg` (ticks, m): shape (m, rows, cols) (`LimitedStrips`)."""
    return LimitedStrips.of(track, states, limited, delay_s, period_s, cell_m, grid).coverage(metered_kg)


@dataclass(frozen=True)
class LimitedStrips:
    """The strips of the machine-limited ticks, for any number of metered columns: the strips are the
    same for every column; a column's product decides only which of them sweep (`maps.ColumnDeposit`)."""

    plan: StripPlan | None      # None: no limited tick
    columns: ColumnDeposit | None
    shape: tuple[int, int]      # the grid's (rows, cols)

    @classmethod
    def of(cls, track: dict, states: SectionStates, limited: np.ndarray, delay_s: float, period_s: float,
           cell_m: float, grid: Grid) -> LimitedStrips:
        """`limited_coverage`'s parameters, less the product."""
        if not limited.any():
            return cls.of_plan(None, grid)
        plan = StripPlan.of(track, states, delay_s, period_s, cell_m, ticks=np.flatnonzero(limited))
        return cls.of_plan(plan, grid)

    @classmethod
    def of_plan(cls, plan: StripPlan | None, grid: Grid) -> LimitedStrips:
        """The limited ticks' strips of `plan` (None: no limited tick)."""
        if plan is None:
            return cls(None, None, (grid.rows, grid.cols))
        return cls(plan, ColumnDeposit(grid, plan.strips.footprint()), (grid.rows, grid.cols))

    def coverage(self, metered_kg: np.ndarray) -> np.ndarray:
        """`limited_coverage` of the columns `metered_kg` (ticks, m): shape (m, rows, cols)."""
        if self.plan is None:
            return np.zeros((metered_kg.shape[1], *self.shape))
        return self.columns.coverage_fraction(self.plan.mass_kg(metered_kg))


def worked_fraction(track: dict, width_m: float, grid: Grid) -> np.ndarray:
    """Share of each cell of `grid` that the whole working width sweeps along the working
    stretches of the true path: the ground the plan means to treat; shape (rows, cols).

    Counted on a raster `WORKED_SUPERSAMPLE` times finer (fewer on very large grids): the share of
    its cells whose centre lies inside the outlines (`WorkedArea`).
    """
    worked = WorkedArea(grid)
    worked.add(track, width_m)
    return worked.fraction()


class WorkedArea:
    """The worked area of `worked_fraction`, added run of work by run of work (`add`), on a fine
    boolean raster of the grid (at most `MAX_WORKED_CELLS` bytes)."""

    def __init__(self, grid: Grid):
        self.grid = grid
        fine = int(math.sqrt(MAX_WORKED_CELLS / (grid.rows * grid.cols)))
        self.fine = max(1, min(WORKED_SUPERSAMPLE, fine))
        self.mask = np.zeros((grid.rows * self.fine, grid.cols * self.fine), bool)

    def add(self, track: dict, width_m: float, first_ticks: int | None = None) -> None:
        """Add the runs of work of `track` (those that begin before tick `first_ticks`, default all: a
        run must lie whole in the track, the tick after its end included if there is one)."""
        dx, dy = self.grid.cell_size
        pose = Poses.of(track)
        rings = []
        for a, b in runs_of(np.asarray(track["implement_on"], bool)):
            if first_ticks is None or a < first_ticks:
                rings += pose.outlines(a, b, width_m / 2, -width_m / 2, pose.vertex_step(a, b))
        # Stretched north-south so the cells are square, as the scan lines need.
        stretch = dx / dy
        west, _, _, north = self.grid.bounds
        fill_outlines(self.mask, [r * (1.0, stretch) for r in rings], west, north * stretch, dx / self.fine)

    def fraction(self) -> np.ndarray:
        """Share of each cell worked, shape (rows, cols)."""
        fine, grid = self.fine, self.grid
        # The fine cells worked in each cell counted slice by slice: exact in any order, so the mask's
        # mean to the bit, without numpy's loop call per row of `fine` fine cells (5 times slower).
        mask = self.mask.view(np.uint8).reshape(grid.rows, fine, grid.cols, fine)
        count = np.zeros((grid.rows, grid.cols), np.uint16)   # at most WORKED_SUPERSAMPLE**2
        for i in range(fine):
            for j in range(fine):
                count += mask[:, i, :, j]
        return count / fine**2


def landing_pass(time_s, pass_index, delay_s: float, ticks=None) -> np.ndarray:
    """The pass of the product metered in each tick (of `ticks`, default all): that of the pose where
    it starts landing, a turn counting with the pass before it (the first pass for anything before it)."""
    time_s = np.asarray(time_s, float)
    if not time_s.size:
        return np.zeros(0, np.int64)
    idx = np.arange(time_s.size) if ticks is None else np.asarray(ticks, np.int64)
    filled = np.maximum.accumulate(np.asarray(pass_index, np.int64))
    pose = np.clip(np.searchsorted(time_s, time_s[idx] + delay_s, side="right") - 1, 0, time_s.size - 1)
    return np.maximum(filled[pose], 0)


def _join_ticks(cell_m: float, tick_m: float) -> int:
    """How many ticks of `tick_m` travel a strip joins: up to half a map cell of `cell_m`."""
    return max(1, int(0.5 * cell_m / tick_m)) if tick_m > 0 else 1


def landing_frame(track: dict, delay_s: float, period_s: float, ticks):
    """Start and end of the landing span of each of `ticks` on the true path and the unit left normal
    there."""
    time_s = np.asarray(track["time_s"], float)
    t0 = time_s[ticks] + delay_s
    x, y = track["x_m"], track["y_m"]
    hx = np.interp(t0, time_s, np.cos(track["heading_rad"]))
    hy = np.interp(t0, time_s, np.sin(track["heading_rad"]))
    norm = np.hypot(hx, hy)
    nx = np.divide(-hy, norm, out=np.zeros(norm.shape), where=norm > 0)
    ny = np.divide(hx, norm, out=np.zeros(norm.shape), where=norm > 0)
    return (np.interp(t0, time_s, x), np.interp(t0, time_s, y), np.interp(t0 + period_s, time_s, x),
            np.interp(t0 + period_s, time_s, y), nx, ny)
