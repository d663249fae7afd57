"""The spinner's pure parts: its spec and pattern (vehicle/spinner.py), its footprint deposited by both
modes of the engine (maps/spread_footprint.py), and the EN 13739 figures (services/sim/spread_pattern.py)."""

import numpy as np
import pytest

from vrsim.common import MapError, VehicleError
from vrsim.maps import AsApplied, ColumnDeposit, SpinnerThrow, footprint_kind, synthetic
from vrsim.services.sim.spread_pattern import catch_tray_test, cv_pct, effective_width_m, overlapped
from vrsim.vehicle.spinner import SpinnerSpec

UTM = "EPSG:32632"
BOUNDS = (500_000.0, 5_300_000.0, 500_100.0, 5_300_100.0)  # 100 m x 100 m
TRIANGLE = ([-18.0, 0.0, 18.0], [0.0, 1.0, 0.0])  # 36 m spread


# --- the spec and its pattern ----------------------------------------------------------------------
def test_shapes_are_normalized_and_the_trapezoid_is_flat_over_the_central_half():
    tri = SpinnerSpec(spread_width_m=36.0).transverse_pattern()
    trap = SpinnerSpec(spread_width_m=36.0, pattern="trapezoidal").transverse_pattern()
    for p in (tri, trap):
        assert np.trapezoid(p.mass_per_m, p.offset_m) == pytest.approx(1.0)
        assert p.extent_m == (-18.0, 18.0)
    assert tri.density(9.0) == pytest.approx(tri.density(0.0) / 2)
    top = trap.density(np.linspace(-9.0, 9.0, 7))
    np.testing.assert_allclose(top, top[0])
    assert trap.density(13.5) == pytest.approx(top[0] / 2) and trap.density(18.5) == 0.0


@pytest.mark.parametrize("keys, message", [
    ({"spread_width_m": 20.0}, "spread_width_m=20 must be at least the driving width width_m=24"),
    ({"spread_width_m": -1.0}, "spread_width_m must be a number > 0 m, got -1.0"),
    ({"throw_distance_m": True}, "throw_distance_m must be a number in [0, 100] m, got True"),
    ({"border_spreading": 1}, "border_spreading must be true or false, got 1"),
    ({"side_steps": 0}, "side_steps must be an integer in [1, 16], got 0"),
    ({"side_steps": 2.0}, "side_steps must be an integer in [1, 16], got 2.0"),
    ({"pattern": "round"}, "pattern must be one of triangular, trapezoidal or a CSV file's path (.csv), "
                           "got 'round'"),
    ({"pattern": ""}, "pattern must be one of triangular, trapezoidal"),
])
def test_bad_keys_are_refused_with_one_line_naming_key_and_value(keys, message):
    with pytest.raises(VehicleError) as err:
        SpinnerSpec(**keys).resolved(".").check_width(24.0)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_border_spreading_cuts_at_the_boundary_and_without_it_a_step_goes_only_when_wholly_outside():
    spec = SpinnerSpec(spread_width_m=36.0, side_steps=4)  # steps of 4.5 m
    room = np.array([np.inf, 20.0, 18.0, 17.9, 9.0, 4.4, 0.0, 10.0])
    np.testing.assert_allclose(spec.side_reach_m(room), [18.0, 18.0, 18.0, 17.9, 9.0, 4.4, 0.0, 10.0])
    plain = SpinnerSpec(spread_width_m=36.0, side_steps=4, border_spreading=False)
    np.testing.assert_allclose(plain.side_reach_m(room), [18.0, 18.0, 18.0, 18.0, 9.0, 4.5, 0.0, 13.5])
    on_off = SpinnerSpec(spread_width_m=36.0, side_steps=1, border_spreading=False)
    np.testing.assert_allclose(on_off.side_reach_m(room), [18.0] * 6 + [0.0, 18.0])


def test_a_side_cut_keeps_the_share_of_its_half_within_the_reach_and_the_centre_of_its_product():
    tri = SpinnerSpec(spread_width_m=36.0).transverse_pattern()
    np.testing.assert_allclose(tri.side_share([1, -1, 1], [18.0, 12.0, 0.0]), [1.0, 1 - (6 / 18) ** 2, 0.0])
    assert tri.side_centre_m(1) == pytest.approx(6.0, abs=1e-3)   # a triangle's centroid: a third out
    assert tri.side_centre_m(-1) == pytest.approx(-6.0, abs=1e-3)


def _csv(tmp_path, text, name="tray.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_measured_profile_is_read_relative_to_the_scenario_folder(tmp_path):
    _csv(tmp_path, "offset_m,mass\n# trays\n-15,0.1\n-5,1.0\n5,1.0\n15,0.2\n")
    spec = SpinnerSpec(pattern="tray.csv", spread_width_m=30.0).resolved(str(tmp_path))
    pattern = spec.transverse_pattern()
    assert spec.pattern == pattern.source == str(tmp_path / "tray.csv")
    np.testing.assert_allclose(pattern.offset_m, [-15, -5, 5, 15])
    assert np.trapezoid(pattern.mass_per_m, pattern.offset_m) == pytest.approx(1.0)
    assert pattern.density(-15.0) * 2 == pytest.approx(pattern.density(15.0))


@pytest.mark.parametrize("text, message", [
    ("", "no rows (a catch-tray profile: lateral offset m, relative mass)"),
    ("offset,mass\n", "no rows"),
    ("-10,1\n0,1\n", "2 row(s): a profile needs at least 3"),
    ("-10,1\n0,-0.5\n10,1\n", "row 2: relative mass -0.5 is negative"),
    ("-10,1\n0,1\n-5,1\n10,1\n", "row 3: offset -5 m does not increase (previous row: 0 m)"),
    ("-10,1\n0,1\n0,1\n10,1\n", "row 3: offset 0 m does not increase"),
    ("-10,1\n0,abc\n10,1\n", "row 2: 'abc' is not a finite number"),
    ("-10,1\n0,nan\n10,1\n", "row 2: 'nan' is not a finite number"),
    ("-10,1\n0,1,2\n10,1\n", "row 2: '0,1,2' has 3 field(s), expected 2"),
    ("-10,0\n0,0\n10,0\n", "every relative mass is zero"),
    ("-10,1\n0,1\n20,1\n", "row 3: offset 20 m lies beyond half the spread width (18 m)"),
    ("-10,1\n-5,1\n0,1\n", "no mass left of the centre line"),
])
def test_a_bad_profile_names_file_row_and_value(tmp_path, text, message):
    path = _csv(tmp_path, text)
    with pytest.raises(VehicleError) as err:
        SpinnerSpec(pattern=str(path)).resolved(".")
    assert f"pattern {path}: {message}" in str(err.value)


# --- the footprint ---------------------------------------------------------------------------------
def _throw(x, y, dx, dy, side, reach, throw=0.0, pattern=TRIANGLE):
    x, y = np.asarray(x, float), np.asarray(y, float)
    return SpinnerThrow(x, y, x + dx, y + dy, side, reach, *pattern, throw_distance_m=throw)


def test_the_kind_is_registered_and_refuses_bad_items():
    assert footprint_kind("spinner") is SpinnerThrow
    with pytest.raises(MapError, match="side must be"):
        _throw([0.0], [0.0], 0.0, 1.0, 0, 18.0)
    with pytest.raises(MapError, match=r"reach_m\[0\]=0 must be finite and > 0"):
        _throw([0.0], [0.0], 0.0, 1.0, 1, 0.0)
    with pytest.raises(MapError, match="holds no mass within its reach"):
        _throw([0.0], [0.0], 0.0, 1.0, 1, 5.0, pattern=([-18.0, -10.0, 10.0, 18.0], [1.0, 0.0, 0.0, 1.0]))


def test_each_disc_throws_its_half_behind_it_with_the_pattern_weights():
    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=1.0)
    acc = AsApplied(g)
    # Driving north along x = 500 050 from y = 5 300 060 to 5 300 061, product lands 10 m behind.
    acc.deposit(_throw([500_050.0] * 2, [5_300_060.0] * 2, 0.0, 1.0, [1, -1], 18.0, throw=10.0), [1.0, 2.0])
    kg = acc.applied_kg
    rows = np.flatnonzero(kg.sum(axis=1) > 0)
    assert rows.size == 1 and g.cell_centres()[1][rows[0]] == pytest.approx(5_300_050.5)
    across = kg[rows[0]]
    x = np.asarray(g.cell_centres()[0]) - 500_050.0
    # Left of travel (north) is west: the left disc's 1 kg lies at x < 0, the right disc's 2 kg at x > 0.
    assert across[x < 0].sum() == pytest.approx(1.0) and across[x > 0].sum() == pytest.approx(2.0)
    # A triangle's mass over each metre: exact (the weights integrate the density).
    edges = np.arange(0.0, 19.0)
    expected = 2 * ((1 - edges[:-1] / 18) ** 2 - (1 - edges[1:] / 18) ** 2)  # 2 kg over [0, 18]
    np.testing.assert_allclose(across[(x > 0) & (x < 18)], expected, rtol=1e-9)
    assert acc.coverage_fraction[rows[0], (x > -18) & (x < 18)].min() == pytest.approx(1.0)


def test_a_cut_side_puts_its_whole_product_inside_its_reach():
    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=1.0)
    acc = AsApplied(g)
    acc.deposit(_throw([500_050.0], [5_300_050.0], 0.0, 1.0, [-1], 6.0), [1.0])
    x = np.asarray(g.cell_centres()[0]) - 500_050.0
    across = acc.applied_kg.sum(axis=0)
    assert across.sum() == pytest.approx(1.0) and across[(x < 0) | (x > 6)].sum() == 0.0
    # The triangle's shape over [0, 6], renormalized: mass per metre falls from 1 at 0 to 2/3 at 6.
    inner = across[(x > 0) & (x < 6)]
    assert inner[0] / inner[-1] == pytest.approx((1 - 0.5 / 18) / (1 - 5.5 / 18), rel=1e-9)


def test_a_spinner_deposits_alike_in_both_modes_at_any_heading():
    g = synthetic.uniform(BOUNDS, UTM, cell_size_m=2.0)
    rng = np.random.default_rng(5)
    k = 120
    x, y = rng.uniform(500_020.0, 500_080.0, k), rng.uniform(5_300_020.0, 5_300_080.0, k)
    heading = rng.uniform(0, 2 * np.pi, k)
    step = rng.uniform(0.0, 1.5, k)
    step[:3] = 0.0  # standing still: the product at the disc
    side = np.where(np.arange(k) % 2, 1, -1)
    fp = SpinnerThrow(x, y, x + step * np.cos(heading), y + step * np.sin(heading), side,
                      rng.uniform(3.0, 30.0, k), [-15.0, -5.0, 5.0, 15.0], [0.0, 1.0, 1.0, 0.0],
                      throw_distance_m=4.0)
    mass = rng.uniform(0.0, 2.0, (k, 2))
    mass[rng.random((k, 2)) < 0.2] = 0.0
    passes = np.arange(k) // 40
    cols = ColumnDeposit(g, fp, pass_index=passes).apply(mass)
    for j in range(2):
        acc = AsApplied(g)
        acc.deposit(fp, mass[:, j], pass_index=passes)
        for name in ("applied_kg_ha", "coverage_fraction", "overlap_fraction", "overlap_kg"):
            np.testing.assert_allclose(getattr(cols, name)[j], getattr(acc, name), rtol=1e-12, atol=1e-12,
                                       err_msg=name)
        np.testing.assert_array_equal(cols.pass_count[j], acc.pass_count)
        assert acc.applied_kg.sum() + acc.outside_kg == pytest.approx(mass[:, j].sum(), rel=1e-12)


# --- EN 13739 figures ------------------------------------------------------------------------------
def test_triangles_twice_the_driving_width_overlap_to_a_flat_rate():
    assert cv_pct(*TRIANGLE, 18.0) == pytest.approx(0.0, abs=1e-9)
    assert cv_pct(*TRIANGLE, 18.0, "racetrack") == pytest.approx(0.0, abs=1e-9)
    _, rate = overlapped(*TRIANGLE, 18.0)
    np.testing.assert_allclose(rate, 1.0)


def test_triangles_one_and_a_half_times_the_driving_width_give_the_hand_computed_cv():
    # By hand, driving width w = 1, triangles of half-width a = 0.75 and height 1 centred on every
    # pass. Across [0, 1] only the passes at 0 and 1 reach: f = 1 - 4x/3 on [0, 1/4], 2 - 4/3 = 2/3 on
    # [1/4, 3/4] (both flanks), 1 - 4(1 - x)/3 on [3/4, 1].
    #   mean    = 2 * (1/4 - (4/3)(1/32)) + (1/2)(2/3) = 5/12 + 1/3 = 3/4  (the triangle's area)
    #   mean sq = 2 * (3/4) * (1 - (2/3)**3) / 3 + (1/2)(4/9) = 19/54 + 2/9 = 31/54
    #   CV      = sqrt(31/54 - 9/16) / (3/4) = 14.34 %
    hand = np.sqrt(31 / 54 - 9 / 16) / 0.75 * 100
    assert hand == pytest.approx(14.34, abs=0.01)
    assert cv_pct(*TRIANGLE, 24.0) == pytest.approx(hand, abs=0.5)
    assert cv_pct(*TRIANGLE, 24.0, "racetrack") == pytest.approx(hand, abs=0.5)


def test_to_and_fro_mirrors_every_other_pass_and_racetrack_does_not():
    skewed, mirrored = ([-10.0, -6.0, 10.0], [0.0, 1.0, 0.0]), ([-10.0, 6.0, 10.0], [0.0, 1.0, 0.0])
    assert cv_pct(*skewed, 10.0) != pytest.approx(cv_pct(*skewed, 10.0, "racetrack"), abs=0.1)
    # Mirroring the pattern changes neither (the same field driven from its other side).
    for mode in ("to_and_fro", "racetrack"):
        assert cv_pct(*skewed, 10.0, mode) == pytest.approx(cv_pct(*mirrored, 10.0, mode), abs=1e-9)
    # A symmetric pattern overlaps alike both ways.
    assert cv_pct(*TRIANGLE, 21.0) == pytest.approx(cv_pct(*TRIANGLE, 21.0, "racetrack"), abs=1e-9)


def test_effective_width_is_the_largest_driving_width_within_the_limit():
    w = effective_width_m(*TRIANGLE)
    assert cv_pct(*TRIANGLE, w) <= 15.0 < cv_pct(*TRIANGLE, w + 0.02)
    assert 24.0 < w < 25.0
    tight = effective_width_m(*TRIANGLE, limit_pct=1.0)
    assert 18.0 < tight < 19.0 and cv_pct(*TRIANGLE, tight) <= 1.0 < cv_pct(*TRIANGLE, tight + 0.02)
    spike = ([-1.0, -0.001, 0.0, 0.001, 1.0], [0.0, 0.0, 1.0, 0.0, 0.0])  # 2 mm wide: no width evens it
    assert effective_width_m(*spike) == 0.0


def test_simulated_catch_trays_agree_with_the_overlapped_pattern():
    spec = SpinnerSpec(spread_width_m=36.0, throw_distance_m=8.0)
    test = catch_tray_test(spec, spec.transverse_pattern(), 24.0, 0.5)
    assert test.passes == 3 and test.in_width.sum() == 48
    assert test.total_pct[test.in_width].mean() == pytest.approx(100.0, rel=1e-6)
    assert test.cv_pct == pytest.approx(cv_pct(*TRIANGLE, 24.0), abs=0.5)
    assert test.effective_width_m == pytest.approx(effective_width_m(*TRIANGLE), abs=0.2)
    flat = catch_tray_test(spec, spec.transverse_pattern(), 18.0, 0.5)
    assert flat.cv_pct < 0.5
    assert catch_tray_test(SpinnerSpec(spread_width_m=60.0), SpinnerSpec(spread_width_m=60.0)
                           .transverse_pattern(), 12.0, 0.5).passes == 5
