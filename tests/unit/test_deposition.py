"""The deposition engine's extension point (maps/footprint.py): the registry of footprint kinds, and a
new kind (a weighted transverse pattern) deposited by both modes of the engine without changing it."""

import numpy as np
import pytest

from vrsim.common import MapError
from vrsim.maps import (
    AsApplied,
    ColumnDeposit,
    Samples,
    Strips,
    footprint,
    footprint_kind,
    register_footprint,
    synthetic,
)

UTM = "EPSG:32632"
BOUNDS = (500_000.0, 5_300_000.0, 500_100.0, 5_300_100.0)  # 100 m x 100 m


class Triangle:
    """A test kind: product thrown east-west across each item's point in a triangular pattern
    ``spread_m`` wide, over a band ``band_m`` north-south (a spinner's transverse pattern, flattened)."""

    kind = "test_triangle"

    def __init__(self, x, y, spread_m, band_m=0.5):
        self.x, self.y = np.asarray(x, float), np.asarray(y, float)
        self.spread_m, self.band_m = np.broadcast_to(np.asarray(spread_m, float), self.x.shape), band_m

    @property
    def items(self) -> int:
        return self.x.size

    def samples(self, step, metres_per_unit, part):
        first = part.indices(self.items)[0]
        x, y, spread = self.x[part], self.y[part], self.spread_m[part] / metres_per_unit
        # One sampling for every item, whatever `part` holds (an item's samples must not depend on it).
        n = max(1, int(np.ceil(self.spread_m.max(initial=0.0) / metres_per_unit / step)))
        v = (np.arange(n) + 0.5) / n - 0.5  # across, in (-1/2, 1/2)
        weight = 1.0 - 2.0 * np.abs(v)
        band = self.band_m / metres_per_unit
        yield Samples(first + np.arange(x.size), x[:, None] + v[None, :] * spread[:, None],
                      np.broadcast_to(y[:, None], (x.size, n)), spread / n, np.full(x.size, band),
                      spread * band, weight / weight.sum())


@pytest.fixture
def triangle(monkeypatch):
    """The test kind registered for one test (the registry left as it was after)."""
    monkeypatch.setattr(footprint, "FOOTPRINTS", dict(footprint.FOOTPRINTS))
    return register_footprint(Triangle)


def test_registry_knows_section_strips_and_refuses_unknown_and_taken_names(triangle):
    assert footprint_kind("section_strips") is Strips and footprint_kind("test_triangle") is Triangle
    with pytest.raises(MapError, match="not one of section_strips, .*test_triangle"):
        footprint_kind("no_such_kind")
    taken = type("Other", (), {"kind": "section_strips"})
    with pytest.raises(MapError, match="registered already"):
        register_footprint(taken)
    with pytest.raises(MapError, match="'kind'"):
        register_footprint(type("Nameless", (), {}))


def test_a_new_kind_deposits_its_pattern_in_both_modes_alike(triangle):
    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=5.0)
    rng = np.random.default_rng(11)
    k = 200
    x, y = rng.uniform(500_010.0, 500_090.0, k), rng.uniform(5_300_005.0, 5_300_095.0, k)
    x[-5:] = 500_099.0  # half thrown off the grid
    spread = rng.uniform(4.0, 24.0, k)
    mass = rng.uniform(0.0, 2.0, (k, 3))
    mass[rng.random((k, 3)) < 0.2] = 0.0
    fp = footprint_kind("test_triangle")(x, y, spread)
    cols = ColumnDeposit(g, fp, pass_index=np.arange(k) // 50).apply(mass)
    for j in range(3):
        acc = AsApplied(g)
        acc.deposit(fp, mass[:, j], pass_index=np.arange(k) // 50)
        for name in ("applied_kg_ha", "coverage_fraction", "overlap_fraction", "overlap_kg"):
            np.testing.assert_allclose(getattr(cols, name)[j], getattr(acc, name), rtol=1e-12, atol=1e-12,
                                       err_msg=name)
        np.testing.assert_array_equal(cols.pass_count[j], acc.pass_count)
        assert acc.applied_kg.sum() + acc.outside_kg == pytest.approx(mass[:, j].sum(), rel=1e-12)
        assert acc.outside_kg > 0


def test_a_weighted_pattern_puts_most_product_under_its_centre(triangle):
    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=5.0)
    acc = AsApplied(g)
    acc.deposit(Triangle([500_052.5], [5_300_052.5], 25.0, band_m=1.0), 1.0)  # centre of cell (9, 10)
    row = acc.applied_kg[9]
    # A triangle 25 m wide over five 5 m cells: the triangle's area over each, 2, 6, 9, 6, 2 (/ 25).
    np.testing.assert_allclose(row[8:13], np.array([2, 6, 9, 6, 2]) / 25, rtol=1e-12)
    assert row.sum() == pytest.approx(1.0) and acc.coverage_fraction[9, 10] == pytest.approx(1 / 5)
