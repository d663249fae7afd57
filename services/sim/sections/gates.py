"""Gates: commands from the look-aheads, and the gates following them after their latencies, in ticks.

Vectorized over ticks (running maxima, shifts) and causal, so stepping in batches of any size gives
the gates of one step over the whole run.
"""

from __future__ import annotations

import numpy as np


def command(wanted_on, wanted_off, on_first: bool, before) -> np.ndarray:
    """The terminal's command per tick from the two look-aheads: bool (m, sections), one row per tick.

    ``wanted_on[t]``: product is wanted where it would start landing if the section were commanded
    on at t; ``wanted_off[t]``: ... where it would stop landing if commanded off at t. When both
    agree the command follows them. When only the longer look-ahead wants product, the section
    switches (or stays) on; when only the shorter one does, it keeps its state (on: product still
    lands on wanted ground until it could stop; off: starting now would land on unwanted ground).
    The result: product starts and stops landing where wanted starts and stops (as far as the
    look-aheads predicted it), except that a gap shorter than the two delays' difference is
    bridged (overlap) and an island that short is skipped: the section cannot stop and restart, or
    start and stop, in time.

    ``before`` (sections,) is the command before the first tick (causal: a tick's command depends
    on that and the ticks up to it only).
    """
    decided = wanted_on | ~wanted_off
    value = wanted_on if on_first else wanted_off
    last = np.where(decided, np.arange(decided.shape[0], dtype=np.int32)[:, None], np.int32(-1))
    np.maximum.accumulate(last, axis=0, out=last)
    held = _along(value, np.maximum(last, 0))
    return np.where(last >= 0, held, np.asarray(before, bool)[None, :])


class GateLine:
    """Gates (bool per section) following commands after their latencies in ticks, across `push` calls.

    Each command takes effect `on_ticks` (switching on) or `off_ticks` (switching off) after it is
    given, and a gate follows the most recent command that has taken effect, so an on command
    cancelled before it took effect never opens the gate. All gates are closed before tick 0.
    """

    def __init__(self, on_ticks: int, off_ticks: int, sections: int):
        self.on, self.off = on_ticks, off_ticks
        self.span = max(on_ticks, off_ticks)
        self.history = np.zeros((self.span, sections), bool)  # the last `span` commands
        self.arrived = np.full(sections, -1, np.int64)  # tick of the command each gate follows
        self.value = np.zeros(sections, bool)  # each gate's state

    def push(self, commanded, tick: int) -> np.ndarray:
        """Gate states of the ticks `tick`, `tick` + 1, ... whose commands are `commanded` (m, sections)."""
        m = commanded.shape[0]
        if m == 0:
            return np.zeros(commanded.shape, bool)
        ext = np.concatenate((self.history, commanded))  # from tick - span
        t = tick + np.arange(m, dtype=np.int64)[:, None]
        src_on, src_off = ext[self.span - self.on:][:m], ext[self.span - self.off:][:m]
        events = np.maximum(np.where(src_on & (t - self.on >= 0), t - self.on, -1),
                            np.where(~src_off & (t - self.off >= 0), t - self.off, -1))
        arrived = np.maximum.accumulate(np.maximum(events, self.arrived[None, :]), axis=0)
        fresh = arrived > self.arrived[None, :]
        index = np.clip(arrived - (tick - self.span), 0, ext.shape[0] - 1)
        gates = np.where(fresh, _along(ext, index), self.value[None, :])
        self.arrived, self.value = arrived[-1], gates[-1]
        self.history = ext[ext.shape[0] - self.span:]
        return gates

    def state(self) -> dict:
        """What the gates carry to the next `push`, as plain data (JSON-safe)."""
        return {"history": self.history.tolist(), "arrived": self.arrived.tolist(),
                "value": self.value.tolist()}

    def set_state(self, state: dict) -> None:
        """Continue from what `state` returned."""
        sections = self.value.size
        self.history = np.asarray(state["history"], bool).reshape(self.span, sections)
        self.arrived = np.asarray(state["arrived"], np.int64).reshape(sections)
        self.value = np.asarray(state["value"], bool).reshape(sections)


def gate(commanded, on_ticks: int, off_ticks: int) -> np.ndarray:
    """Gate state per tick of a whole run, latencies in ticks (see `GateLine`): bool, shape as `commanded`."""
    return GateLine(on_ticks, off_ticks, commanded.shape[1]).push(commanded, 0)


def _along(values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``np.take_along_axis(values, rows, axis=0)`` of 2-d arrays, as one flat take (2x faster)."""
    cols = values.shape[1]
    return np.take(values.reshape(-1), rows * cols + np.arange(cols), mode="clip")
