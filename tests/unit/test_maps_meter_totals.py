"""Several meters' totals (`maps.meter_totals.MeterTotals`) against an `AsApplied` each, and the
as-applied reads band by band against the whole grid's."""

import numpy as np
import pytest

import vrsim.maps.as_applied as as_applied
from tests.unit.test_maps_applied import field, passes
from vrsim.common import MapError
from vrsim.maps import AsApplied
from vrsim.maps.footprint import Samples, Strips
from vrsim.maps.meter_totals import MeterTotals


def _strips():
    x0, y0, x1, y1, mass = passes(150.0, width_m=12.0, step_m=0.2, angle_deg=25.0)
    x1 = x1 + np.where(np.arange(x0.size) % 5, 0.0, 3.0)   # strips cut in several patterns
    return Strips(x0, y0, x1, y1, np.full(x0.size, 12.0)), mass, np.arange(x0.size) * 4 // x0.size


def _assert_like_each(totals, each):
    """Single precision against double: coverage to 1e-6, product to a few parts in a million."""
    for j, acc in enumerate(each):
        np.testing.assert_allclose(totals.coverage_fraction(j), acc.coverage_fraction, rtol=0, atol=1e-6)
        np.testing.assert_allclose(totals.applied_kg_ha(j), acc.applied_kg_ha, rtol=1e-5, atol=1e-6)
        assert totals.outside_kg(j) == pytest.approx(acc.outside_kg, rel=1e-9, abs=1e-12)
        assert totals.total_kg[j] == pytest.approx(acc.total_kg, rel=1e-12)
    assert totals.items == each[0].items


def test_meters_beside_a_run_equal_an_as_applied_each():
    """The run's raster stays its own deposit's bit for bit; the meters' coverage and product are each
    one's own `AsApplied`'s to single precision (a meter putting product on other items than the rest
    gets its own swept raster)."""
    strips, mass, pass_index = _strips()
    k = np.arange(strips.items)
    masses = np.column_stack([np.full(k.size, mass), np.linspace(0.0, 2 * mass, k.size),
                              np.where(k % 7, mass, 0.0), np.where(k % 7, 2 * mass, 0.0)])
    alone = AsApplied(field())
    alone.deposit(strips, mass, pass_index=pass_index)
    run, totals = AsApplied(field()), MeterTotals(field(), masses.shape[1])
    half = k.size // 2   # two deposits: the meters part ways in the first
    for part in (slice(0, half), slice(half, None)):
        run.deposit(Strips(*(a[part] for a in (strips.x0, strips.y0, strips.x1, strips.y1, strips.width_m))),
                    mass, pass_index=pass_index[part], others=[(totals, masses[part])])
    for name in ("applied_kg", "coverage_fraction", "overlap_fraction", "overlap_kg", "pass_count"):
        np.testing.assert_array_equal(getattr(run, name), getattr(alone, name))
    each = [AsApplied(field()) for _ in range(masses.shape[1])]
    for acc, m in zip(each, masses.T, strict=True):
        acc.deposit(strips, m)
    _assert_like_each(totals, each)
    # The first meter's items with product are the second's (linspace: all but the first) but not the
    # third's; the third and fourth share theirs.
    assert totals._of[2] == totals._of[3] != totals._of[0] and len(totals._swept) == 3


class _Weighted:
    """A footprint whose items' samples carry unequal shares of its product (as a spinner's throw)."""

    kind = "weighted-test"

    def __init__(self, strips):
        self.strips = strips

    @property
    def items(self):
        return self.strips.items

    def samples(self, step, unit, part):
        for s in self.strips.samples(step, unit, part):
            weight = np.linspace(1.0, 3.0, s.per_item).reshape(s.x.shape[1:])
            yield Samples(s.items, s.x, s.y, s.ext_x, s.ext_y, s.swept, weight / weight.sum())


def test_meters_deposited_alone_with_weighted_samples_equal_an_as_applied_each():
    strips, mass, _ = _strips()
    footprint = _Weighted(strips)
    masses = np.column_stack([np.full(strips.items, mass), np.full(strips.items, 0.5 * mass)])
    totals = MeterTotals(field(), 2)
    totals.deposit(footprint, masses)
    each = [AsApplied(field()) for _ in range(2)]
    for acc, m in zip(each, masses.T, strict=True):
        acc.deposit(footprint, m)
    _assert_like_each(totals, each)
    assert len(totals._swept) == 1   # both put product on every item: one swept raster


def test_meter_totals_refuse_bad_product_and_meters():
    strips, mass, _ = _strips()
    with pytest.raises(MapError, match=r"mass_kg\[3, 1\]"):
        MeterTotals(field(), 2).deposit(strips, np.where(np.arange(strips.items)[:, None] == 3, [mass, -1.0],
                                                         mass))
    with pytest.raises(MapError, match="meters=0"):
        MeterTotals(field(), 0)


def test_reads_band_by_band_are_the_whole_grids_to_the_bit(monkeypatch):
    """The per-cell reads go a band of cell rows at a time: the same bits as over the whole grid at
    once, the open pass's raster included."""
    strips, mass, pass_index = _strips()
    names = ("applied_kg", "coverage_fraction", "overlap_fraction", "overlap_kg")
    acc = AsApplied(field())
    acc.deposit(strips, mass, pass_index=pass_index)   # the last pass left open
    monkeypatch.setattr(as_applied, "_BAND_SUBCELLS", 10**9)
    whole = {name: getattr(acc, name) for name in names}
    for band in (1, 3 * acc.raster.subcells**2 * acc.grid.cols):
        monkeypatch.setattr(as_applied, "_BAND_SUBCELLS", band)
        for name in names:
            np.testing.assert_array_equal(getattr(acc, name), whole[name])


@pytest.mark.parametrize("angle_deg", [0.0, 25.0, 90.0])
def test_the_passes_capped_sums_held_sparse_are_the_dense_ones_to_the_bit(angle_deg):
    """`maps.pass_capped`: the sums of the sub-cells two passes or more swept kept on their own, the
    others read off the raster: the overlap figures of dense sums, bit for bit, an open pass included
    and once closed; product deposited without a pass turns the sums dense as they stand."""
    x0, y0, x1, y1, mass = passes(150.0, width_m=12.0, step_m=0.2, angle_deg=angle_deg)
    x1 = x1 + np.where(np.arange(x0.size) % 5, 0.0, 3.0)   # ticks reaching over the next: overlap
    strips = Strips(x0, y0, x1, y1, np.full(x0.size, 13.0))   # 13 m swaths 12 m apart: passes meet
    pass_index = np.arange(x0.size) * 7 // x0.size
    sparse, dense = AsApplied(field()), AsApplied(field())
    dense._capped.to_dense(None)   # no pass yet: dense zeros, the sums as a dense array adds them
    names = ("overlap_fraction", "overlap_kg", "pass_count")
    for acc in (sparse, dense):
        acc.deposit(strips, mass, pass_index=pass_index)
    assert sparse._capped.dense is None and sparse._capped.at.size > 0
    for name in names:   # the last pass open
        np.testing.assert_array_equal(getattr(sparse, name), getattr(dense, name))
    assert sparse.overlap_kg.sum() > 0
    again = Strips(x0[:900], y0[:900], x1[:900], y1[:900], np.full(900, 13.0))   # over passes 0 and 1
    for acc in (sparse, dense):   # its ground swept a second and a third time
        acc.deposit(again, mass, pass_index=9)
        acc.deposit(again, mass, pass_index=10)
        acc.close_pass()
    assert sparse._capped.dense is None
    for name in names:
        np.testing.assert_array_equal(getattr(sparse, name), getattr(dense, name))
    for acc in (sparse, dense):
        acc.add_strips(x0[:500], y0[:500], x1[:500], y1[:500], 12.0, mass)   # without a pass
        acc.deposit(again, mass, pass_index=11)
        acc.close_pass()
    assert sparse._capped.dense is not None
    for name in names:
        np.testing.assert_array_equal(getattr(sparse, name), getattr(dense, name))


def test_a_batch_spread_piece_by_piece_is_the_whole_batchs_to_the_bit(monkeypatch):
    """A batch's boxes are added corner by corner, a piece of samples at a time (bounded temporaries):
    the figures of the run's raster and of the meters beside it are those of whole pieces, bit for bit."""
    strips, mass, pass_index = _strips()
    masses = np.column_stack([np.full(strips.items, mass), np.linspace(0.0, mass, strips.items)])
    names = ("applied_kg", "coverage_fraction", "overlap_fraction", "overlap_kg", "pass_count", "outside_kg")

    def deposited():
        acc, totals = AsApplied(field()), MeterTotals(field(), 2)
        acc.deposit(_Weighted(strips), mass, pass_index=pass_index, others=[(totals, masses)])
        meters = [(totals.applied_kg_ha(j), totals.coverage_fraction(j), totals.outside_kg(j))
                  for j in range(2)]
        return [getattr(acc, name) for name in names] + [f for figures in meters for f in figures]

    whole = deposited()
    monkeypatch.setattr(as_applied, "_PIECE_SAMPLES", 4099)   # several pieces a batch
    for a, b in zip(deposited(), whole, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_finished_raster_reads_the_same_figures_and_takes_no_deposit():
    strips, mass, pass_index = _strips()
    acc = AsApplied(field())
    acc.deposit(strips, mass, pass_index=pass_index)   # the last pass left open: `finish` closes it
    names = ("applied_kg", "applied_kg_ha", "coverage_fraction", "overlap_fraction", "overlap_kg",
             "pass_count", "outside_kg")
    before = {name: getattr(acc, name) for name in names}
    window, rates = acc.applied_kg_in(slice(2, 7), slice(3, 9)), acc.as_grid().rates_kg_ha
    acc.finish()
    assert acc._acc is None and acc._capped is None   # the sub-cells given back
    for name in names:
        np.testing.assert_array_equal(getattr(acc, name), before[name])
    assert acc.pass_count.dtype == np.int64
    np.testing.assert_array_equal(acc.applied_kg_in(slice(2, 7), slice(3, 9)), window)
    np.testing.assert_array_equal(acc.as_grid().rates_kg_ha, rates)
    with pytest.raises(ValueError):
        acc.coverage_fraction[0, 0] = 1.0   # the figures kept are read-only
    with pytest.raises(MapError, match="finished"):
        acc.deposit(strips, mass)
