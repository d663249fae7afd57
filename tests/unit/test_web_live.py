"""The live view's state (services/bus/web/live.py): the view grid from map/info, the applied layer
painted across the working width, and the frames and deltas the browsers get."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from vrsim.common import ServiceError
from vrsim.services.bus import messages
from vrsim.services.bus.web import parse_listen, picture
from vrsim.services.bus.web.bridge import _decode
from vrsim.services.bus.web.live import (
    FIELDS,
    RECORD_FIELDS,
    AppliedLayer,
    Batch,
    LiveView,
    SectionGeometry,
    ViewGrid,
)

INFO = {"bounds": [1000.0, 5000.0, 1100.0, 5060.0], "cell_size": [2.0, 2.0], "rows": 30, "cols": 50,
        "min_rate_kg_ha": 100.0, "max_rate_kg_ha": 200.0}


def pose(run, tick, x, y=5030.0, heading=0.0):
    return messages.Pose(run, tick, tick * 0.05, x, y, x, y, heading, 2.5, 2.5, True, x - 1000.0)


def rate(run, tick, x, y=5030.0, applied=160.0, width=12.0, on=True, mask="0x3f"):
    return messages.RateSample(run, tick, tick * 0.05, x, y, 150.0, applied, 0.01, width, mask, on, [150.0],
                               [0.01])


def shaft(run, tick):
    return messages.ShaftState(run, tick, tick * 0.05, 50.0, 49.0, 0.04, 0.2, [50.0])


def batch(records, fields=FIELDS) -> Batch:
    """Records as the bridge decodes them off the bus."""
    stream = {messages.Pose: "pose", messages.ShaftState: "shaft", messages.RateSample: "rate"}
    return _decode(stream[type(records[0])], messages.encode_batch(records), fields[stream[type(records[0])]])


SIX = SectionGeometry(np.full(6, 2.0), np.arange(5.0, -6.0, -2.0))  # six 2 m sections, left to right


def known(view: LiveView, run: str) -> None:
    """The run's scenario read (as the bridge does from monitor/run): its six sections."""
    view.set_run_info(run, {"scenario": "s"}, SIX)


def view_with_map() -> LiveView:
    view = LiveView()
    view.set_map(INFO, ViewGrid.from_info(INFO), 1)
    return view


# ---------------------------------------------------------------------------------------- grid
def test_view_grid_is_the_map_grid_when_small_and_coarser_when_large():
    grid = ViewGrid.from_info(INFO)
    assert (grid.rows, grid.cols, grid.stride, grid.cell_x_m) == (30, 50, 1, 2.0)
    big = dict(INFO, rows=3000, cols=5000)
    coarse = ViewGrid.from_info(big, max_cells=500_000)
    assert coarse.stride == 6 and coarse.cells <= 500_000
    assert (coarse.rows, coarse.cols, coarse.cell_x_m) == (500, 834, 12.0)


@pytest.mark.parametrize("change, needle", [
    ({"bounds": [0, 0, 1]}, "bounds"),
    ({"cell_size": [2.0, 0.0]}, "cell_size"),
    ({"cell_size": [2.0, float("nan")]}, "cell_size"),
    ({"rows": 0}, "rows"),
    ({"cols": 2.5}, "cols"),
    ({"rows": True}, "rows"),
])
def test_view_grid_refuses_map_info_that_does_not_fit(change, needle):
    with pytest.raises(ServiceError, match=f"map/info: .*{needle}"):
        ViewGrid.from_info(dict(INFO, **change))


def test_view_grid_as_a_maps_grid_finds_the_cell_of_each_centre_and_nothing_outside():
    grid = ViewGrid.from_info(INFO)
    x, y = grid.centres()
    found = grid.as_grid().lookup(x, y)
    np.testing.assert_array_equal(found.row * grid.cols + found.col, np.arange(grid.cells))
    outside = grid.as_grid().lookup(np.array([999.9, 1100.1, 1050.0, np.nan]),
                                    np.array([5030.0, 5030.0, 5060.1, 5030.0]))
    assert outside.row.tolist() == [-1, -1, -1, -1] and not outside.inside.any()
    corner = grid.as_grid().lookup(np.array([1000.0]), np.array([5060.0]))  # north-west corner
    assert (corner.row.tolist(), corner.col.tolist()) == ([0], [0])


# ---------------------------------------------------------------------------------------- layer
def test_a_sample_paints_across_its_width_perpendicular_to_the_heading():
    layer = AppliedLayer(ViewGrid.from_info(INFO))
    # Heading east at y = 5031 (row 14): a 12 m width spans y 5025..5037, rows 11..17, one column.
    layer.paint(1, [1051.0], [5031.0], [0.0], [12.0], [0.0], [160.0])
    rows, cols = np.divmod(np.flatnonzero(layer.line_m), 50)
    assert sorted(set(rows.tolist())) == list(range(11, 18)) and set(cols.tolist()) == {25}
    # Heading north: across is east-west, x 1045..1057, columns 22..28, one row.
    layer = AppliedLayer(ViewGrid.from_info(INFO))
    layer.paint(1, [1051.0], [5031.0], [math.pi / 2], [12.0], [0.0], [160.0])
    rows, cols = np.divmod(np.flatnonzero(layer.line_m), 50)
    assert set(rows.tolist()) == {14} and sorted(set(cols.tolist())) == list(range(22, 29))


def test_offset_shifts_the_strip_to_the_left_of_the_heading():
    layer = AppliedLayer(ViewGrid.from_info(INFO))
    layer.paint(1, [1051.0], [5031.0], [0.0], [2.0], [6.0], [160.0])  # east: left is north
    rows, _ = np.divmod(np.flatnonzero(layer.line_m), 50)
    assert set(rows.tolist()) == {11}  # y 5036..5038


def test_cells_show_the_mean_of_their_samples_and_unusable_samples_are_left_out():
    layer = AppliedLayer(ViewGrid.from_info(INFO))
    layer.paint(1, [1051.0, 1051.1], [5031.0, 5031.0], [0.0, 0.0], [1.0, 1.0], [0.0, 0.0], [100.0, 200.0])
    assert layer.since(-1) == {"i": [14 * 50 + 25], "v": [150.0]}
    touched = layer.paint(2, [1051.0, 1051.0, 1051.0, np.nan], [5031.0] * 4, [0.0, np.nan, 0.0, 0.0],
                          [0.0, 1.0, 1.0, 1.0], [0.0] * 4, [160.0, 160.0, np.nan, 160.0])
    assert touched == 0 and layer.since(1) == {"i": [], "v": []}


def test_a_cell_weighs_each_sample_by_its_line_across_it_and_shows_zero_rates():
    layer = AppliedLayer(ViewGrid.from_info(INFO))
    # Heading east in column 25: one 2 m line fills row 14 (y 5030..5032) at 90 kg/ha, another
    # (y 5029..5031) crosses it for 1 m at 180 kg/ha: (2 * 90 + 1 * 180) / 3 = 120.
    layer.paint(1, [1051.0, 1051.0], [5031.0, 5030.0], [0.0, 0.0], [2.0, 2.0], [0.0, 0.0], [90.0, 180.0])
    painted = layer.since(-1)
    assert dict(zip(painted["i"], painted["v"], strict=True)) == {14 * 50 + 25: 120.0, 15 * 50 + 25: 180.0}
    layer.paint(2, [1061.0], [5031.0], [0.0], [2.0], [0.0], [0.0])  # sections open, nothing metered
    assert layer.since(1) == {"i": [14 * 50 + 30], "v": [0.0]}


def test_section_masks_paint_the_open_sections_once_the_implement_is_known():
    view = view_with_map()
    view.on_pose(batch([pose("r", 0, 1051.0, 5031.0)]))
    # Heading east, six 2 m sections: the leftmost (bit 0, y 5035..5037: rows 11, 12) and the
    # rightmost (bit 5, y 5025..5027: rows 16, 17) open; the four between (rows 13..15) closed.
    view.on_rate(batch([rate("r", 0, 1051.0, 5031.0, width=4.0, mask="0x21")]))
    view.frame()
    assert view.layer.painted == 0  # waits for the run's implement
    known(view, "r")
    view.frame()
    rows, cols = np.divmod(np.flatnonzero(view.layer.line_m), 50)
    assert sorted(set(rows.tolist())) == [11, 12, 16, 17] and set(cols.tolist()) == {25}
    # A mask that is not one of six sections paints nothing; all gates closed neither.
    view.on_pose(batch([pose("r", t, 1071.0, 5031.0) for t in (1, 2)]))
    view.on_rate(batch([rate("r", 1, 1071.0, 5031.0, mask="0x40"),
                        rate("r", 2, 1071.0, 5031.0, mask="0x3f")]))
    view.on_rate(batch([rate("r", 3, 1081.0, 5031.0, mask="0x0", width=0.0)]))
    view.frame()
    assert (np.flatnonzero(view.layer.line_m) % 50 == 25).all()


# ---------------------------------------------------------------------------------------- view
def test_frames_only_when_something_changed_and_deltas_carry_what_changed_since():
    view = view_with_map()
    hello_seq = view.frame()
    assert view.frame() is None  # nothing new
    view.on_pose(batch([pose("r", t, 1010.0 + t) for t in range(5)]))
    known(view, "r")
    view.on_rate(batch([rate("r", t, 1010.0 + t) for t in range(5)]))
    seq = view.frame()
    assert seq == hello_seq + 1
    doc = view.delta(hello_seq, view.epoch)
    assert doc["type"] == "frame" and doc["pose"]["tick"] == 4 and doc["rate"]["tick"] == 4
    assert len(doc["applied"]["i"]) > 0 and doc["points"] == [[0.2, None, None, 150.0, 160.0]]
    assert view.delta(seq, view.epoch)["applied"]["i"] == []  # nothing painted after it


def test_a_new_run_starts_over_and_tells_the_browser_to():
    view = view_with_map()
    assert view.on_pose(batch([pose("a", 0, 1010.0)])) == "a"
    view.on_rate(batch([rate("a", 0, 1010.0)]))
    view.frame()
    epoch = view.epoch
    assert view.on_pose(batch([pose("b", 0, 1020.0)])) == "b"
    assert view.epoch == epoch + 1 and view.layer.painted == 0
    assert view.delta(view.seq, epoch)["type"] == "hello"


def test_a_run_left_behind_is_not_shown_again():
    view = view_with_map()
    view.on_pose(batch([pose("a", 0, 1010.0)]))
    view.on_pose(batch([pose("b", 0, 1010.0)]))
    assert view.adopt_run("a") is False  # a status from before b started
    assert view.on_pose(batch([pose("a", 1, 1011.0)])) is None and view.run_id == "b"
    assert view.adopt_run("c") is True and view.run_id == "c"


def test_a_rate_sample_that_comes_before_its_pose_is_painted_when_the_pose_comes():
    view = view_with_map()
    view.on_pose(batch([pose("r", 0, 1010.0)]))
    known(view, "r")
    view.on_rate(batch([rate("r", t, 1010.0 + t) for t in range(3)]))
    view.frame()  # a frame paints what came since the last
    assert view.layer.painted > 0 and view.waiting.tick.tolist() == [1, 2]
    before = view.layer.painted
    view.on_pose(batch([pose("r", t, 1010.0 + t) for t in (1, 2)]))
    view.frame()
    assert view.waiting is None and view.layer.painted > before and view.unoriented == 0


def test_a_rate_sample_whose_pose_never_comes_is_counted_not_kept():
    view = view_with_map()
    view.on_pose(batch([pose("r", 0, 1010.0), pose("r", 2, 1012.0)]))  # tick 1 lost
    view.on_rate(batch([rate("r", 1, 1011.0)]))
    assert view.waiting is None and view.unoriented == 1


def test_backfill_paints_the_past_once_and_puts_its_chart_points_first():
    view = view_with_map()
    view.on_pose(batch([pose("r", t, 1040.0 + t) for t in range(10, 12)]))
    view.on_rate(batch([rate("r", t, 1040.0 + t) for t in range(10, 12)]))
    view.frame()
    poses = batch([pose("r", t, 1010.0 + t) for t in range(12)], RECORD_FIELDS)
    shafts = batch([shaft("r", t) for t in range(12)], RECORD_FIELDS)
    rates = batch([rate("r", t, 1010.0 + t, applied=100.0 + t) for t in range(12)], RECORD_FIELDS)
    assert view.backfill(poses, shafts, rates, stride=5) == 10  # ticks 10, 11 came live
    assert view.backfill(poses, shafts, rates, stride=5) == 0  # not twice
    other = batch([rate("other", t, 1010.0 + t) for t in range(12)], RECORD_FIELDS)
    assert view.backfill(poses, shafts, other, stride=5) == 0
    epoch = view.epoch
    view.set_catchup("r", "done")
    assert view.epoch == epoch + 1
    points = [p for _, p in view.history]
    assert [p[0] for p in points] == [0.0, 0.25, 0.55]  # ticks 0 and 5 from the records, then live 11
    assert points[1] == [0.25, 50.0, 49.0, 150.0, 105.0]
    assert view.hello()["catchup"] == {"state": "done", "ticks": 10, "note": ""}


def test_a_map_on_another_grid_mid_run_asks_for_the_run_so_far():
    view = LiveView()
    view.on_pose(batch([pose("r", 0, 1010.0)]))
    view.on_rate(batch([rate("r", 0, 1010.0)]))  # no map yet: nothing painted
    assert view.set_map(INFO, ViewGrid.from_info(INFO), 1) is True
    assert view.first_tick["rate"] == 1  # live painting starts after the last sample seen
    assert view.set_map(INFO, ViewGrid.from_info(INFO), 2) is False  # same grid: the layer stays


def test_ticks_held_back_when_the_runs_grid_comes_are_painted_once_from_the_records():
    """A view that got a run's first samples before its map (on the grid served before): those still
    held back for the run's sections or for their pose are the records' to paint on the new grid,
    and each tick counts once, as in a view that saw them all live (#17: painted from both)."""
    coarse = dict(INFO, cell_size=[4.0, 4.0], rows=15, cols=25)
    poses = [pose("r", t, 1010.0 + t) for t in range(8)]
    rates = [rate("r", t, 1010.0 + t, applied=100.0 + 10.0 * t) for t in range(8)]
    view = LiveView()
    view.set_map(coarse, ViewGrid.from_info(coarse), 1)
    view.on_pose(batch(poses[:3]))
    view.on_rate(batch(rates[:4]))  # 0-2 wait for the sections, 3 for its pose as well
    assert view.set_map(INFO, ViewGrid.from_info(INFO), 2) is True  # the run's map
    known(view, "r")
    view.on_pose(batch(poses[3:]))
    view.on_rate(batch(rates[4:]))
    shafts = [shaft("r", t) for t in range(8)]
    records = (batch(records, RECORD_FIELDS) for records in (poses, shafts, rates))
    assert view.backfill(*records, stride=1) == 4
    view.frame()
    live = view_with_map()
    live.on_pose(batch(poses))
    known(live, "r")
    live.on_rate(batch(rates))
    live.frame()
    assert view.layer.line_m.tolist() == live.layer.line_m.tolist()
    assert view.layer.since(-1) == live.layer.since(-1) and view.layer.painted > 0


# ---------------------------------------------------------------------------------------- picture, CLI
def test_png_has_the_map_size_the_scale_colours_and_transparent_nodata():
    from PIL import Image

    colours = picture.scale(INFO)
    rates = np.array([[100.0, 200.0, np.nan]])
    img = Image.open(io.BytesIO(picture.render_png(rates, 1, 3, colours)))
    assert img.size == (3, 1)
    px = [img.getpixel((i, 0)) for i in range(3)]
    assert px[0] == (*colours["lut"][0], 255) and px[1] == (*colours["lut"][-1], 255) and px[2][3] == 0


@pytest.mark.parametrize("text", ["8448", "tcp/127.0.0.1:8448", "127.0.0.1:", "127.0.0.1:70000", ":80"])
def test_listen_must_be_host_and_port(text):
    with pytest.raises(ServiceError, match="expected HOST:PORT"):
        parse_listen(text)


def test_listen_parses_ipv4_and_ipv6():
    assert parse_listen("127.0.0.1:8448") == ("127.0.0.1", 8448)
    assert parse_listen("[::1]:9000") == ("::1", 9000)


def test_a_message_of_several_runs_is_refused():
    with pytest.raises(ServiceError, match="several runs"):
        batch([pose("a", 0, 1010.0), pose("b", 1, 1011.0)])
