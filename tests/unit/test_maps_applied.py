"""Synthetic maps and as-applied accumulation."""

import numpy as np
import pytest
from affine import Affine

from vrsim.common import MapError
from vrsim.maps import AsApplied, Grid, synthetic

UTM = "EPSG:32632"
BOUNDS = (500_000.0, 5_300_000.0, 500_100.0, 5_300_100.0)  # 100 m x 100 m


# ---------------------------------------------------------------------- synthetic
@pytest.mark.parametrize("kind", ["uniform", "zones", "gradient", "random_field", "checkerboard"])
def test_synthetic_deterministic_and_valid(kind):
    make = getattr(synthetic, kind)
    a, b = make(BOUNDS, UTM, cell_size_m=5.0, seed=7), make(BOUNDS, UTM, cell_size_m=5.0, seed=7)
    np.testing.assert_array_equal(a.rates_kg_ha, b.rates_kg_ha)
    assert (a.rows, a.cols) == (20, 20) and a.bounds == BOUNDS
    assert a.source == f"synthetic:{kind}" and np.isfinite(a.rates_kg_ha).all() and (a.rates_kg_ha >= 0).all()


def test_synthetic_seed_changes_random_maps():
    for kind in ("zones", "random_field"):
        make = getattr(synthetic, kind)
        one, two = make(BOUNDS, UTM, seed=1), make(BOUNDS, UTM, seed=2)
        assert not np.array_equal(one.rates_kg_ha, two.rates_kg_ha)


def test_synthetic_shapes():
    u = synthetic.uniform(BOUNDS, UTM, rate_kg_ha=123.0)
    assert (u.rates_kg_ha == 123.0).all()
    z = synthetic.zones(BOUNDS, UTM, n_zones=4, rate_range_kg_ha=(100, 200), rate_step_kg_ha=25)
    assert set(np.unique(z.rates_kg_ha)) <= {100, 125, 150, 175, 200}
    g = synthetic.gradient(BOUNDS, UTM, low_kg_ha=100, high_kg_ha=200, angle_deg=0.0)
    assert g.rates_kg_ha[0, 0] == 100 and g.rates_kg_ha[0, -1] == 200
    assert (np.diff(g.rates_kg_ha, axis=1) > 0).all() and (np.diff(g.rates_kg_ha, axis=0) == 0).all()
    r = synthetic.random_field(BOUNDS, UTM, cell_size_m=1.0, mean_kg_ha=150, std_kg_ha=20,
                               correlation_length_m=5)
    assert r.rates_kg_ha.mean() == pytest.approx(150) and r.rates_kg_ha.std() == pytest.approx(20, rel=0.01)
    # Smooth: neighbouring cells differ far less than the field's spread.
    assert np.abs(np.diff(r.rates_kg_ha, axis=1)).mean() < 0.3 * r.rates_kg_ha.std()
    c = synthetic.checkerboard(BOUNDS, UTM, cell_size_m=5.0, square_m=20.0, low_kg_ha=100, high_kg_ha=200)
    assert c.rates_kg_ha[-1, 0] == 100 and c.rates_kg_ha[-1, 4] == 200 and c.rates_kg_ha[-5, 0] == 200
    assert (c.rates_kg_ha[-4:, :4] == 100).all()  # one whole 20 m square in the south-west corner


def test_synthetic_validation():
    with pytest.raises(MapError, match="geographic"):
        synthetic.uniform((9, 48, 9.01, 48.01), "EPSG:4326")
    with pytest.raises(MapError, match="rate_kg_ha"):
        synthetic.uniform(BOUNDS, UTM, rate_kg_ha=-1)
    with pytest.raises(MapError, match="cell_size_m"):
        synthetic.zones(BOUNDS, UTM, cell_size_m=0)
    with pytest.raises(MapError, match="bounds"):
        synthetic.gradient((1, 1, 0, 0), UTM)


# ---------------------------------------------------------------------- as-applied
def passes(rate_kg_ha, width_m=10.0, step_m=0.15, angle_deg=0.0, x0=500_000.0, y0=5_300_000.0, size=100.0):
    """Back-and-forth passes of `width_m` covering a `size` square, as ticks of `step_m`."""
    a = np.radians(angle_deg)
    along, across = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    # Passes over a region three times the field's size, so any angle covers the field.
    n_pass = int(np.ceil(size * 3 / width_m))
    s = np.arange(0.0, size * 3, step_m) - size
    segs = []
    for k in range(n_pass):
        off = (k + 0.5) * width_m - size
        start = np.add.outer(s, 0)[:, None] * along + off * across
        segs.append(np.column_stack((start, start + step_m * along)))
    seg = np.concatenate(segs) + [x0, y0, x0, y0]
    mass = rate_kg_ha * width_m * step_m / 10_000.0
    return seg[:, 0], seg[:, 1], seg[:, 2], seg[:, 3], mass


def field(cell=5.0):
    return synthetic.uniform(BOUNDS, UTM, cell_size_m=cell, rate_kg_ha=0.0)


def test_full_coverage_gives_target_rate_and_conserves_mass():
    acc = AsApplied(field())
    x0, y0, x1, y1, mass = passes(150.0)
    acc.add_strips(x0, y0, x1, y1, 10.0, np.full(x0.size, mass))
    np.testing.assert_allclose(acc.applied_kg_ha, 150.0, rtol=1e-9)
    np.testing.assert_allclose(acc.coverage_fraction, 1.0)
    assert acc.applied_kg.sum() + acc.outside_kg == pytest.approx(acc.total_kg, rel=1e-9)
    assert acc.outside_kg > 0  # passes overshoot the field


def test_diagonal_passes_and_chunking():
    x0, y0, x1, y1, mass = passes(200.0, width_m=12.0, step_m=0.2, angle_deg=30.0)
    one = AsApplied(field())
    one.add_strips(x0, y0, x1, y1, 12.0, np.full(x0.size, mass))
    chunked = AsApplied(field())
    for part in np.array_split(np.arange(x0.size), 7):
        chunked.add_strips(x0[part], y0[part], x1[part], y1[part], 12.0, np.full(part.size, mass))
    np.testing.assert_allclose(chunked.applied_kg_ha, one.applied_kg_ha, rtol=1e-9)
    # Sampling at 1/8 cell: per-cell error small, total exact.
    np.testing.assert_allclose(one.applied_kg_ha, 200.0, rtol=0.03)
    assert one.applied_kg_ha.mean() == pytest.approx(200.0, rel=0.005)
    assert one.coverage_fraction.min() > 0.9


def test_partial_strip_coverage_fraction_and_position():
    acc = AsApplied(field(cell=10.0))
    # One 5 m wide, 10 m long strip centred on x = 500 015 (cells 1: 500 010-500 020), row 0 north.
    acc.add_strips(500_015.0, 5_300_100.0, 500_015.0, 5_300_090.0, 5.0, 1.0)
    applied = acc.applied_kg
    assert applied[0, 1] == pytest.approx(1.0) and applied.sum() == pytest.approx(1.0)
    assert acc.coverage_fraction[0, 1] == pytest.approx(0.5)
    assert acc.applied_kg_ha[0, 1] == pytest.approx(100.0)  # 1 kg on a 100 m^2 cell
    grid = acc.as_grid()
    assert grid.rates_kg_ha[0, 1] == pytest.approx(100.0) and np.isnan(grid.rates_kg_ha[5, 5])


def test_zero_length_and_outside_strips():
    acc = AsApplied(field())
    acc.add_strips([500_050.0, 400_000.0], [5_300_050.0, 0.0], [500_050.0, 400_010.0], [5_300_050.0, 0.0],
                   [6.0, 6.0], [2.0, 3.0])
    assert acc.applied_kg.sum() == pytest.approx(2.0) and acc.outside_kg == pytest.approx(3.0)


def test_as_applied_validation():
    with pytest.raises(MapError, match="projected CRS"):
        AsApplied(Grid(np.ones((2, 2)), Affine(0.001, 0, 9, 0, -0.001, 48), "EPSG:4326"))
    acc = AsApplied(field())
    with pytest.raises(MapError, match="mass_kg"):
        acc.add_strips([0.0], [0.0], [1.0], [1.0], 3.0, [-1.0])
    with pytest.raises(MapError, match="non-finite"):
        acc.add_strips([np.nan], [0.0], [1.0], [1.0], 3.0, [1.0])
    with pytest.raises(MapError, match="subcells"):
        AsApplied(field(), subcells=0)


# ---------------------------------------------------------------------- passes and overlap
def test_pass_counts_overlap_area_and_kg():
    # Two 20 m wide passes northwards over 5 m cells, overlapping by 10 m (x 500 025-500 035,
    # columns 5 and 6), each 100 kg/ha; the second in two calls (still one pass).
    acc = AsApplied(field())
    acc.add_strips(500_025.0, 5_300_000.0, 500_025.0, 5_300_100.0, 20.0, 20.0, pass_index=0)
    acc.add_strips(500_035.0, 5_300_000.0, 500_035.0, 5_300_050.0, 20.0, 10.0, pass_index=1)
    acc.add_strips(500_035.0, 5_300_050.0, 500_035.0, 5_300_100.0, 20.0, 10.0, pass_index=[1])
    counts = acc.pass_count
    assert (counts[:, 3:5] == 1).all() and (counts[:, 5:7] == 2).all() and (counts[:, 7:9] == 1).all()
    assert (counts[:, :3] == 0).all() and (counts[:, 9:] == 0).all()
    overlap = acc.overlap_fraction
    np.testing.assert_allclose(overlap[:, 5:7], 1.0)
    assert overlap[:, :5].max() == 0.0 and overlap[:, 7:].max() == 0.0
    # Beyond the first pass: the second pass's product on the overlap, 10 m x 100 m at 100 kg/ha.
    assert acc.overlap_kg.sum() == pytest.approx(10.0)
    np.testing.assert_allclose(acc.applied_kg_ha[:, 5:7], 200.0)


def test_pass_overlapping_itself_and_strips_without_pass():
    acc = AsApplied(field())
    # One pass sweeping the same 10 m twice (a turn) does not overlap itself.
    acc.add_strips([500_050.0, 500_050.0], [5_300_000.0, 5_300_100.0], [500_050.0, 500_050.0],
                   [5_300_100.0, 5_300_000.0], 10.0, [10.0, 10.0], pass_index=[4, 4])
    assert acc.overlap_fraction.max() == 0.0 and acc.overlap_kg.sum() == 0.0
    assert acc.pass_count.max() == 1
    acc.add_strips(500_050.0, 5_300_000.0, 500_050.0, 5_300_100.0, 10.0, 10.0)  # no pass: counts for none
    assert acc.pass_count.max() == 1 and acc.applied_kg_ha.max() == pytest.approx(300.0)
    # A partly swept cell (a quarter) is not put on by that pass.
    part = AsApplied(field(cell=10.0))
    part.add_strips(500_001.25, 5_300_100.0, 500_001.25, 5_300_000.0, 2.5, 1.0, pass_index=0)
    assert part.pass_count.max() == 0 and part.coverage_fraction[:, 0] == pytest.approx(0.25)


# ---------------------------------------------------------------------- ColumnDeposit: many mass columns
def test_strip_map_equals_add_strips_per_column():
    """Oblique, axis-aligned, zero-length and off-grid strips; columns with zero-mass strips (which
    sweep no coverage there): each column's rasters equal AsApplied.add_strips of that column."""
    from vrsim.maps import ColumnDeposit, Strips

    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=5.0)
    rng = np.random.default_rng(3)
    k = 300
    x0 = rng.uniform(499_990.0, 500_110.0, k)
    y0 = rng.uniform(5_299_990.0, 5_300_110.0, k)
    angle, length = rng.uniform(0, 2 * np.pi, k), rng.uniform(0.0, 4.0, k)
    length[:10] = 0.0
    angle[10:60] = 0.0
    x1, y1 = x0 + length * np.cos(angle), y0 + length * np.sin(angle)
    width = rng.uniform(0.5, 12.0, k)
    mass = rng.uniform(0.0, 2.0, (k, 3))
    mass[rng.random((k, 3)) < 0.2] = 0.0
    strip_map = ColumnDeposit(g, Strips(x0, y0, x1, y1, width))
    cols = strip_map.apply(mass)
    for j in range(3):
        acc = AsApplied(g)
        acc.add_strips(x0, y0, x1, y1, width, mass[:, j])
        np.testing.assert_allclose(cols.applied_kg_ha[j], acc.applied_kg_ha, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(cols.coverage_fraction[j], acc.coverage_fraction, rtol=1e-12, atol=1e-12)
        assert cols.outside_kg[j] == pytest.approx(acc.outside_kg, rel=1e-12, abs=1e-12)
    assert cols.applied_kg.sum(axis=(1, 2)) + cols.outside_kg == pytest.approx(mass.sum(axis=0), rel=1e-12)
    with pytest.raises(MapError, match="shape"):
        strip_map.apply(mass[:-1])


def test_strip_map_pass_figures_equal_add_strips_with_passes():
    """Strips in passes (two passes overlapping, one sweeping ground twice) carrying columns of mass,
    some strips empty in some columns: pass count, overlap share and overlap kg, coverage and applied
    rate equal AsApplied.add_strips of each column with the same passes."""
    from vrsim.maps import ColumnDeposit, Strips

    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=5.0)
    rng = np.random.default_rng(5)
    ys = np.arange(5_300_000.0, 5_300_100.0, 1.3)
    x_of_pass = (500_020.0, 500_024.0, 500_024.0, 500_060.3)
    x0 = np.concatenate([np.full(ys.size, x) for x in x_of_pass])
    y0 = np.concatenate([ys] * len(x_of_pass))
    y1 = y0 + 1.3
    x1 = x0 + rng.uniform(-0.2, 0.2, x0.size)
    passes = np.repeat([0, 1, 1, 2], ys.size)   # pass 1 sweeps its ground twice
    width = np.repeat([12.0, 12.0, 12.0, 7.5], ys.size)
    mass = rng.uniform(0.1, 1.0, (x0.size, 4))
    mass[:, 1] = mass[:, 0]                         # columns 0 and 1: one pattern; 2, 3: gaps
    mass[rng.random(x0.size) < 0.1, 2] = 0.0
    mass[:40, 3] = 0.0
    cols = ColumnDeposit(g, Strips(x0, y0, x1, y1, width), pass_index=passes).apply(mass)
    for j in range(mass.shape[1]):
        acc = AsApplied(g)
        acc.add_strips(x0, y0, x1, y1, width, mass[:, j], pass_index=passes)
        np.testing.assert_array_equal(cols.pass_count[j], acc.pass_count)
        for name in ("overlap_fraction", "overlap_kg", "coverage_fraction", "applied_kg_ha"):
            np.testing.assert_allclose(getattr(cols, name)[j], getattr(acc, name), rtol=1e-12, atol=1e-12,
                                       err_msg=name)
    assert cols.overlap_kg[0].sum() > 0 and cols.pass_count.max() == 2
    np.testing.assert_allclose(ColumnDeposit(g, Strips(x0, y0, x1, y1, width)).coverage_fraction(mass),
                               cols.coverage_fraction, rtol=0, atol=0)


def test_applied_kg_in_a_window_is_that_window_of_applied_kg_open_pass_included():
    acc = AsApplied(field(), subcells=3)
    acc.add_strips(500_025.0, 5_300_000.0, 500_031.0, 5_300_100.0, 20.0, 20.0, pass_index=0)
    acc.add_strips(500_045.0, 5_300_010.0, 500_040.0, 5_300_060.0, 12.0, 7.0, pass_index=1)  # open
    whole = acc.applied_kg
    for rows, cols in ((slice(2, 9), slice(3, 12)), (slice(0, 20), slice(0, 20)), (slice(5, 5), slice(0, 4))):
        np.testing.assert_array_equal(acc.applied_kg_in(rows, cols), whole[rows, cols])



def test_closing_the_open_pass_keeps_every_figure_to_the_bit():
    acc = AsApplied(field(), subcells=2)
    acc.add_strips(500_025.0, 5_300_000.0, 500_031.0, 5_300_100.0, 20.0, 20.0, pass_index=0)
    acc.add_strips(500_045.0, 5_300_010.0, 500_040.0, 5_300_060.0, 12.0, 7.0, pass_index=1)  # open
    names = ("applied_kg", "coverage_fraction", "overlap_fraction", "overlap_kg", "pass_count", "outside_kg")
    before = {name: getattr(acc, name) for name in names}
    acc.close_pass()
    acc.close_pass()   # none open: nothing to do
    for name in names:
        np.testing.assert_array_equal(getattr(acc, name), before[name], err_msg=name)


def test_a_pass_off_the_grid_keeps_its_product_once_closed():
    acc = AsApplied(field())
    acc.add_strips(499_000.0, 5_300_050.0, 499_001.0, 5_300_050.0, 3.0, 1.0, pass_index=0)  # off the grid
    acc.add_strips(500_050.0, 5_300_050.0, 500_051.0, 5_300_050.0, 3.0, 1.0, pass_index=1)
    acc.close_pass()
    assert acc.outside_kg == pytest.approx(1.0) and acc.applied_kg.sum() == pytest.approx(1.0)

def test_deposit_with_others_equals_a_deposit_each():
    """Several meters through one footprint: the first (with its passes) as a deposit of its own bit for
    bit; the others, without passes, to the order of the sums (they go pass by pass, as the first)."""
    from vrsim.maps.footprint import Strips

    x0, y0, x1, y1, mass = passes(150.0, width_m=12.0, step_m=0.2, angle_deg=25.0)
    x1 = x1 + np.where(np.arange(x0.size) % 5, 0.0, 3.0)   # strips cut in several patterns
    pass_index = np.arange(x0.size) * 4 // x0.size
    masses = [np.full(x0.size, mass), np.linspace(0.0, 2 * mass, x0.size),
              np.where(np.arange(x0.size) % 7, mass, 0.0)]   # the last: items without product
    strips = Strips(x0, y0, x1, y1, np.full(x0.size, 12.0))
    each = [AsApplied(field()) for _ in masses]
    each[0].deposit(strips, masses[0], pass_index=pass_index)
    for acc, m in zip(each[1:], masses[1:], strict=True):
        acc.deposit(strips, m)
    together = [AsApplied(field()) for _ in masses]
    together[0].deposit(strips, masses[0], pass_index=pass_index,
                        others=list(zip(together[1:], masses[1:], strict=True)))
    a, b = each[0], together[0]
    for name in ("applied_kg", "coverage_fraction", "overlap_fraction", "overlap_kg", "pass_count"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.outside_kg, a.total_kg, a.items) == (b.outside_kg, b.total_kg, b.items)
    for a, b in zip(each[1:], together[1:], strict=True):
        np.testing.assert_allclose(b.applied_kg, a.applied_kg, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(b.coverage_fraction, a.coverage_fraction, rtol=1e-12, atol=1e-15)
        assert b.outside_kg == pytest.approx(a.outside_kg, rel=1e-12, abs=1e-15)
        assert (a.total_kg, a.items) == (b.total_kg, b.items)


@pytest.mark.parametrize("subcells", range(1, 10))
def test_a_cells_sum_of_its_subcells_is_numpys_to_the_bit(subcells):
    """`SubcellRaster.cell_sums` adds in numpy's order (`blocks.sum(axis=(1, 3))`), which the
    as-applied figures were recorded with: a numpy that sums otherwise fails here, not in a figure."""
    from vrsim.maps.subcells import SubcellRaster

    rng = np.random.default_rng(subcells)
    grid = Grid(np.ones((3, 4)), Affine(4.0, 0, 0, 0, -4.0, 12.0), "EPSG:32633")
    shape = (3, subcells, 4, subcells)
    # A wide range of magnitudes (any other order of the additions rounds otherwise), and signed zeros.
    blocks = rng.lognormal(0.0, 3.0, shape) * rng.choice([0.0, -0.0, 1.0, 1.0], shape)
    raster = SubcellRaster(grid, subcells)
    assert raster.cell_sums(blocks).tobytes() == blocks.sum(axis=(1, 3)).tobytes()
    assert raster.cell_means(blocks).tobytes() == blocks.mean(axis=(1, 3)).tobytes()
