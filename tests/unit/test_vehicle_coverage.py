import math
import os

import numpy as np
import pytest
import shapely

from tests.conftest import ROOT
from vrsim.common.errors import VehicleError
from vrsim.vehicle import Field, plan_coverage
from vrsim.vehicle.dubins import _shortest_word, dubins_xy

DATA = os.path.join(ROOT, "tests", "data", "vehicle")


def _fields():
    return {
        "rectangle": Field.rectangle(240.0, 400.0),
        "l_field": Field.from_file(os.path.join(DATA, "l_field.geojson")),
        "u_field": Field.from_file(os.path.join(DATA, "u_field.zip")),
    }


FIELDS = _fields()


@pytest.mark.parametrize("name", sorted(FIELDS))
def test_swaths_cover_the_inner_area(name):
    path = plan_coverage(FIELDS[name], 12.0, headland_passes=1)
    assert path.worked_area_ha / (path.inner.area / 1e4) >= 0.98
    # No gap between neighbouring swath lines: spacing never exceeds the width (+1 %).
    gaps = np.diff(np.sort(path.swath_offsets_m)) - path.width_m
    assert gaps.max() <= 0.01 * path.width_m


@pytest.mark.parametrize("name", sorted(FIELDS))
def test_path_is_continuous_and_on_in_work_only(name):
    field = FIELDS[name]
    path = plan_coverage(field, 12.0, headland_passes=1)
    for a, b in zip(path.segments[:-1], path.segments[1:], strict=True):
        assert np.allclose(a.xy[-1], b.xy[0], atol=1e-6)
        assert a.kind == "turn" or b.kind == "turn" or (a.kind == b.kind == "headland")
    kinds = {s.kind for s in path.segments}
    assert kinds == {"headland", "swath", "turn"}
    for seg in path.segments:
        assert seg.implement_on == (seg.kind != "turn")
        if seg.kind != "turn":  # worked passes stay inside the field
            assert field.polygon.buffer(1e-6).contains(shapely.LineString(seg.xy))
    # Turns are smooth: heading changes at most one arc step per vertex (no kinks at joins).
    d = np.diff(path.xy, axis=0)
    h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    swath_ends = np.abs(np.diff(h)) > 0.2
    assert swath_ends.sum() <= 4 * sum(s.kind == "headland" for s in path.segments)  # only ring corners


def test_swaths_parallel_to_heading_and_serpentine():
    path = plan_coverage(FIELDS["rectangle"], 12.0, headland_passes=0)
    swaths = [s for s in path.segments if s.kind == "swath"]
    assert len(swaths) == 20  # 240 m / 12 m
    dirs = np.array([np.sign(s.xy[-1, 1] - s.xy[0, 1]) for s in swaths])
    assert np.all(dirs[::2] == dirs[0]) and np.all(dirs[1::2] == -dirs[0])
    assert all(abs(s.xy[-1, 0] - s.xy[0, 0]) < 1e-6 for s in swaths)  # north-south
    across = plan_coverage(FIELDS["rectangle"], 12.0, headland_passes=0, heading_deg=90.0)
    sw = [s for s in across.segments if s.kind == "swath"]
    assert len(sw) == 34 and all(abs(s.xy[-1, 1] - s.xy[0, 1]) < 1e-6 for s in sw)


def test_u_turn_or_bulb_by_spacing():
    start = (0.0, 0.0, math.pi / 2)
    assert _shortest_word(start, (12.0, 0.0, -math.pi / 2), 6.0)[0] == "RSR"
    assert _shortest_word(start, (-12.0, 0.0, -math.pi / 2), 6.0)[0] == "LSL"
    assert _shortest_word(start, (-8.0, 0.0, -math.pi / 2), 6.0)[0] == "RLR"  # bulb: 8 m < 2 r
    for end in [(-12.0, 0.0, -math.pi / 2), (-8.0, 3.0, -math.pi / 2), (30.0, 40.0, 1.0)]:
        xy = dubins_xy(start, end, 6.0, step_m=0.1)
        assert np.allclose(xy[-1], end[:2]) and np.allclose(xy[0], start[:2])
        d = np.diff(xy, axis=0)
        h = np.arctan2(d[:, 1], d[:, 0])
        assert abs(math.remainder(h[0] - start[2], 2 * math.pi)) < 0.02
        assert abs(math.remainder(h[-1] - end[2], 2 * math.pi)) < 0.02
        # curvature never tighter than the radius: heading change per metre <= 1/r
        dh = np.abs(np.vectorize(math.remainder)(np.diff(h), 2 * math.pi))
        assert np.all(dh / np.hypot(*d[1:].T) <= 1 / 6.0 * 1.05)


def test_locate_is_on_the_polyline():
    path = plan_coverage(FIELDS["l_field"], 12.0)
    s = np.linspace(0, path.length_m, 5001)
    x, y, h, seg, on = path.locate(s)
    line = shapely.LineString(path.xy)
    assert np.max(shapely.distance(shapely.points(x, y), line)) < 1e-6
    assert np.all(np.diff(seg) >= 0) and seg[-1] == len(path.segments) - 1
    kinds = np.array(path.kinds())[seg]
    assert np.all(on == (kinds != "turn"))
    x0, y0, *_ = path.locate(-5.0)
    assert (x0, y0) == tuple(path.xy[0])


@pytest.mark.parametrize("kwargs, match", [
    (dict(width_m=0.0), "width_m must be a number > 0"),
    (dict(width_m=-3), "width_m must be a number > 0"),
    (dict(width_m=12.0, headland_passes=-1), "headland_passes"),
    (dict(width_m=12.0, turn_radius_m=0), "turn_radius_m must be"),
    (dict(width_m=12.0, heading_deg=float("nan")), "heading_deg"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(VehicleError, match=match):
        plan_coverage(FIELDS["rectangle"], **kwargs)


def test_field_too_narrow_for_one_swath():
    strip = Field.rectangle(45.0, 300.0)
    with pytest.raises(VehicleError, match="too narrow for one swath"):
        plan_coverage(strip, 12.0, headland_passes=2, turn_radius_m=2.0)
    with pytest.raises(VehicleError, match="too narrow for one swath"):
        plan_coverage(Field.rectangle(10.0, 300.0), 12.0, headland_passes=0)
    assert len(plan_coverage(Field.rectangle(12.0, 300.0), 12.0, headland_passes=0).segments) == 1


def test_turning_radius_the_field_cannot_hold():
    with pytest.raises(VehicleError, match="cannot hold turn_radius_m=40"):
        plan_coverage(Field.rectangle(60.0, 300.0), 6.0, headland_passes=1, turn_radius_m=40.0)


def test_field_with_an_obstacle_hole():
    outer = FIELDS["rectangle"]
    holed = type(outer)(outer.polygon.difference(outer.polygon.centroid.buffer(25.0)), outer.crs, "holed")
    path = plan_coverage(holed, 12.0, headland_passes=1)
    rings = [s for s in path.segments if s.kind == "headland"]
    assert len(rings) == 4  # two halves around the boundary, two around the obstacle
    assert path.worked_area_ha / (path.inner.area / 1e4) >= 0.98
    obstacle = shapely.Polygon(holed.polygon.interiors[0]).buffer(-0.01)
    for seg in path.segments:
        if seg.kind != "turn":
            assert not shapely.LineString(seg.xy).intersects(obstacle)


def test_default_heading_follows_the_longest_edge():
    path = plan_coverage(Field.rectangle(400.0, 100.0), 12.0, headland_passes=0)
    assert path.heading_deg == pytest.approx(90.0)
    assert all(abs(s.xy[-1, 1] - s.xy[0, 1]) < 1e-6 for s in path.segments if s.kind == "swath")
