"""Passes: the runs of work a track falls into, numbered in order (-1 where the implement is off).

A pass is a run of ``implement_on`` cut again wherever the heading has turned by half a circle (a
closing headland loop or a spiral is several passes). Within a pass a section's strip never lands on
its own earlier strip, so coverage switching updates its coverage map only where a pass ends.
"""

from __future__ import annotations

import math

import numpy as np


class PassTracker:
    """Pass number of each tick (int, -1 where the implement is off), carried across `step` calls.

    Runs of ``implement_on`` are numbered in order, a run cut again each time its heading has turned
    by half a circle since the piece began; batches give the numbers of one call.

    A piece turning less than half a circle cannot lay its strip on its own earlier strip (except
    where the inner end of the implement pivots in a tight turn); the cut is greedy, so heading
    noise around a multiple of 180 degrees does not cut a straight stretch into many. The heading
    is unwrapped by whole turns counted in integers, so the turned angle is the same however the
    ticks come in batches.
    """

    def __init__(self):
        self.next_id = 0
        self.current = -1  # the open pass, -1 if none
        self.reference = 0.0  # unwrapped heading where the open piece began
        self.turns = 0  # whole turns unwrapped so far
        self.last_heading = None

    def step(self, heading_rad, implement_on) -> np.ndarray:
        """Pass number of the next ticks: heading (rad, math convention) and bool, shape (m,) -> int (m,)."""
        on = np.asarray(implement_on, bool)
        h = np.asarray(heading_rad, float)
        out = np.full(on.size, -1, np.int64)
        if not on.size:
            return out
        prev = h[0] if self.last_heading is None else self.last_heading
        jumps = np.rint(np.diff(h, prepend=prev) / (2 * math.pi)).astype(np.int64)
        turns = self.turns - np.cumsum(jumps)
        unwrapped = h + 2 * math.pi * turns
        self.turns, self.last_heading = int(turns[-1]), float(h[-1])
        for a, b in runs_of(on):
            if a > 0 or self.current < 0:  # a new run of work: a new pass
                self._begin(unwrapped[a])
            pos = a
            while pos < b:
                turned = np.abs(unwrapped[pos:b] - self.reference) >= math.pi
                cut = pos + int(np.argmax(turned)) if turned.any() else b
                out[pos:cut] = self.current
                if cut < b:
                    self._begin(unwrapped[cut])
                pos = cut
        if not on[-1]:
            self.current = -1
        return out

    def state(self) -> dict:
        """What the tracker carries to the next `step`, as plain data (JSON-safe; heading in rad)."""
        return {"next_id": self.next_id, "current": self.current, "reference": self.reference,
                "turns": self.turns, "last_heading": self.last_heading}

    def set_state(self, state: dict) -> None:
        """Continue from what `state` returned."""
        self.next_id, self.current = int(state["next_id"]), int(state["current"])
        self.reference, self.turns = float(state["reference"]), int(state["turns"])
        last = state["last_heading"]
        self.last_heading = None if last is None else float(last)

    def _begin(self, heading: float) -> None:
        self.current, self.next_id = self.next_id, self.next_id + 1
        self.reference = float(heading)


def pass_index(heading_rad, implement_on) -> np.ndarray:
    """Pass number of each tick of a whole track (int, shape (n,); -1 where off; see `PassTracker`)."""
    return PassTracker().step(heading_rad, implement_on)


def runs_of(on: np.ndarray) -> list[tuple[int, int]]:
    """(first, end) tick indices of each run of True in boolean `on`, end exclusive."""
    edges = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [on.size]))
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if on.size and on[a]]

