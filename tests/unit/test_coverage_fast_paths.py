"""Coverage section control's vectorized paths against straightforward references, on random tracks.

The coverage map's marks (all sections' landed strips outlined at once, `Poses.outline_runs`, and
filled by the scan-line rasterizer) and its reads (`CoverageRaster.flagged`, chunked) must give the
very cells and counts of plain loops doing the same arithmetic: ring by ring, row by row, point by
point.
"""

import numpy as np
import pytest
import shapely

from vrsim.services.sim.sections.coverage import CoverageRaster
from vrsim.services.sim.sections.strips import Poses, Strip
from vrsim.vehicle import Implement


def _random_track(rng, n):
    """A wandering track (turns as tight as a 3 m radius, stops) and its poses, m."""
    speed = np.clip(rng.normal(1.5, 1.0, n), 0.0, None) * 0.05
    curvature = np.clip(rng.normal(0, 0.03, n).cumsum(), -0.8, 0.8) / 3.0   # 1/m
    heading = np.cumsum(curvature * speed) + rng.uniform(0, 6.3)
    x = 30 + np.cumsum(speed * np.cos(heading))
    y = 30 + np.cumsum(speed * np.sin(heading))
    return Poses(x, y, np.cos(heading), np.sin(heading))


def _implement(rng):
    widths = tuple(rng.uniform(0.5, 3.0, rng.integers(1, 6)))
    return Implement(width_m=sum(widths), sections=len(widths), section_widths_m=widths)


def _reference_rings(pose, landed, strip, step):
    """The rings of each section's runs, piece by piece (16 vertices along, 15 m), in plain loops."""
    rings = []
    for s in range(landed.shape[1]):
        col = np.concatenate(([False], landed[:, s], [False]))
        starts = [i for i in range(col.size - 1) if col[i + 1] and not col[i]]
        for first in starts:
            end = next(i for i in range(first + 1, col.size) if not col[i + 1])
            last = min(end, pose.x_m.size - 1)
            idx = list(range(first, last, step)) + [last]
            for k in range(0, max(len(idx) - 1, 1), 15):
                piece = idx[k:k + 16]
                ring = [(pose.x_m[i] - pose.sin[i] * strip.edges_m[s][0],
                         pose.y_m[i] + pose.cos[i] * strip.edges_m[s][0]) for i in piece]
                ring += [(pose.x_m[i] - pose.sin[i] * strip.edges_m[s][1],
                          pose.y_m[i] + pose.cos[i] * strip.edges_m[s][1]) for i in piece[::-1]]
                rings.append(ring)
    return rings


def _reference_fill(state, rings, west, north, size, value):
    """OR `value` into the cells whose centre lies inside a ring (even-odd, half-open), row by row."""
    rows, cols = state.shape
    for ring in rings:
        for r in range(rows):
            xs = []
            for (xa, ya), (xb, yb) in zip(ring, ring[1:] + ring[:1], strict=True):
                fa, fb = (north - ya) / size - 0.5, (north - yb) / size - 0.5
                if np.floor(min(fa, fb)) < r <= np.floor(max(fa, fb)):
                    yc = north - (r + 0.5) * size
                    xs.append(xa + (yc - ya) / (yb - ya) * (xb - xa))
            xs.sort()
            for x0, x1 in zip(xs[0::2], xs[1::2], strict=True):
                c0 = int(np.clip(np.ceil((x0 - west) / size - 0.5), 0, cols))
                c1 = int(np.clip(np.ceil((x1 - west) / size - 0.5), 0, cols))
                state[r, c0:c1] |= value


@pytest.mark.parametrize("seed", range(4))
def test_marks_fill_the_cells_of_the_plain_loops(seed):
    rng = np.random.default_rng(seed)
    implement, pose = _implement(rng), _random_track(rng, 700)
    field = shapely.box(0, 0, 60, 60)
    raster = CoverageRaster(field, 0.5, margin_m=implement.width_m)
    strip = Strip.across(implement, raster.cell_m)
    landed = rng.random((699, implement.sections)) < 0.5
    landed = np.repeat(landed[::50], 50, axis=0)[:699]   # runs of 50 ticks
    landed[rng.random(landed.shape) < 0.02] ^= True      # and some of one tick
    want = raster.state.copy()
    raster.mark(strip, pose, 0, landed)
    _reference_fill(want, _reference_rings(pose, landed, strip, pose.vertex_step(0, 699)),
                    raster.west, raster.north, raster.cell_m, np.uint8(1))
    assert (raster.state & 1).sum() > 300
    np.testing.assert_array_equal(raster.state, want)


@pytest.mark.parametrize("seed", range(3))
def test_reads_count_the_points_of_the_plain_loop(seed):
    rng = np.random.default_rng(seed)
    implement, pose = _implement(rng), _random_track(rng, 9000)   # reads in several chunks
    field = shapely.Polygon([(20, 20), (45, 22), (42, 45), (22, 40)])   # the track leaves it
    raster = CoverageRaster(field, 0.4, margin_m=implement.width_m)
    raster.state[rng.random(raster.state.shape) < 0.3] |= np.uint8(1)
    strip = Strip.across(implement, raster.cell_m)
    treated, outside = raster.flagged(strip, pose.x_m, pose.y_m, pose.cos, pose.sin)
    # Point by point across the strip: cell units in float32, clipped to the raster, truncated to a cell.
    inv = 1.0 / raster.cell_m
    x = ((pose.x_m - raster.west) * inv).astype(np.float32)
    y = ((raster.north - pose.y_m) * inv).astype(np.float32)
    sin, cos = pose.sin.astype(np.float32), pose.cos.astype(np.float32)
    want = np.zeros((pose.x_m.size, strip.counts.size, 2), np.int64)
    for p, section in enumerate(np.repeat(np.arange(strip.counts.size), strip.counts)):
        off = np.float32(strip.offsets_m[p] * inv)
        col = np.clip(x - sin * off, 0, raster.cols - 1).astype(int)
        row = np.clip(y - cos * off, 0, raster.rows - 1).astype(int)
        code = raster.state[row, col]
        want[:, section, 0] += code & 1
        want[:, section, 1] += code >> 4   # outside the field: the high nibble's bit
    assert want[..., 0].any() and want[..., 1].any()
    np.testing.assert_array_equal(treated, want[..., 0])
    np.testing.assert_array_equal(outside, want[..., 1])
