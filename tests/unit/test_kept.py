"""What a run keeps for its pictures (`services.sim.kept`): fed in parts of any size, the same as fed
whole (the bounded run's parts against the in-process run's arrays)."""

import numpy as np
import pytest

from vrsim.services.sim.kept import MAX_TRACK_POINTS, SERIES_KEYS, PathPoints, SeriesWindow


def _track(n: int, step_at: int | None):
    t = np.arange(n) * 0.05 + 0.05
    rx = np.full(n, 150.0)
    if step_at is not None:
        rx[step_at:] = 200.0
    on = np.ones(n, bool)
    on[:50] = False
    columns = {k: np.sin(t * (i + 1)) for i, k in enumerate(SERIES_KEYS)}
    columns.update(time_s=t, prescribed_kg_ha=rx)
    return columns, on


def _fed(columns: dict, on, cuts) -> dict:
    window = SeriesWindow()
    for a, b in zip([0, *cuts], [*cuts, len(on)], strict=True):
        window.add({k: v[a:b] for k, v in columns.items()}, on[a:b])
    return window.finish()


@pytest.mark.parametrize("step_at", [None, 120, 4000, 4001])
@pytest.mark.parametrize("cuts", [[], [1], [4000], [7, 3999, 4001, 4002], list(range(500, 6000, 500))])
def test_the_series_window_fed_in_parts_is_the_window_fed_whole(step_at, cuts):
    columns, on = _track(6000, step_at)
    whole, parts = _fed(columns, on, []), _fed(columns, on, cuts)
    t = whole["time_s"]
    start = columns["time_s"][step_at] - 10.0 if step_at is not None else columns["time_s"][0]
    assert t[0] == pytest.approx(max(start, columns["time_s"][0]), abs=0.051) and t[-1] - t[0] < 60.0
    for key in SERIES_KEYS:
        assert np.array_equal(whole[key], parts[key]), key


def test_path_points_fed_in_parts_are_every_stride_th_tick_of_the_run():
    x = np.arange(100_000, dtype=float)
    whole, parts = PathPoints.for_ticks(x.size), PathPoints.for_ticks(x.size)
    whole.add(x, -x)
    for a in range(0, x.size, 3001):
        parts.add(x[a:a + 3001], -x[a:a + 3001])
    assert all(np.array_equal(a, b) for a, b in zip(whole.xy(), parts.xy(), strict=True))
    assert whole.xy()[0].size <= MAX_TRACK_POINTS + 1 and whole.xy()[0][1] == whole.stride
