"""Grid geometry, lookup (nearest, bilinear, CRS), sample, info, reproject, overlap, policy."""

import math

import numpy as np
import pytest
import shapely
from affine import Affine

from vrsim.common import MapError
from vrsim.maps import Grid, RatePolicy, grid_from_bounds, utm_crs_for
from vrsim.maps.crs import WGS84, transform_xy

UTM32 = "EPSG:32632"


def small_grid():
    # 3 rows x 4 cols of 10 m, NW corner (1000, 2030); one nodata cell.
    rates = np.array([[1, 2, 3, 4], [5, 6, np.nan, 8], [9, 10, 11, 12]], dtype=float)
    return Grid(rates, Affine(10, 0, 1000, 0, -10, 2030), UTM32, source="test")


def test_geometry():
    g = small_grid()
    assert (g.rows, g.cols) == (3, 4)
    assert g.cell_size == (10.0, 10.0)
    assert g.bounds == (1000.0, 2000.0, 1040.0, 2030.0)
    assert g.cell_area_m2 == 100.0
    x, y = g.cell_centres()
    np.testing.assert_allclose(x, [1005, 1015, 1025, 1035])
    np.testing.assert_allclose(y, [2025, 2015, 2005])


def test_lookup_row_zero_is_north_and_edges():
    g = small_grid()
    # Cells are half-open: west and north edges belong to the cell, east and south edges do not.
    res = g.lookup([1001, 1039.9, 1015, 1020, 1025, 999.9, 1040.0, 1020, np.nan],
                   [2029, 2000.1, 2015, 2030.0, 2015, 2015, 2015, 2000.0, 2015])
    np.testing.assert_array_equal(res.row, [0, 2, 1, 0, 1, -1, -1, -1, -1])
    np.testing.assert_array_equal(res.col, [0, 3, 1, 2, 2, -1, -1, -1, -1])
    np.testing.assert_array_equal(res.inside, [True] * 5 + [False] * 4)
    np.testing.assert_array_equal(res.rate_kg_ha[:4], [1, 12, 6, 3])
    assert np.isnan(res.rate_kg_ha[4:]).all()  # nodata cell, then outside points


def test_rate_at_matches_lookup():
    g = small_grid()
    rng = np.random.default_rng(1)
    x = rng.uniform(990, 1050, 500)
    y = rng.uniform(1990, 2040, 500)
    vec = g.lookup(x, y).rate_kg_ha
    scalar = np.array([g.rate_at(a, b) for a, b in zip(x, y, strict=True)])
    np.testing.assert_array_equal(np.isnan(vec), np.isnan(scalar))
    np.testing.assert_array_equal(vec[~np.isnan(vec)], scalar[~np.isnan(scalar)])
    assert math.isnan(g.rate_at(float("nan"), 2015.0))


def test_bilinear_interpolates_between_centres_and_falls_back_on_nodata():
    rates = np.array([[0.0, 10.0], [20.0, 30.0]])
    g = Grid(rates, Affine(1, 0, 0, 0, -1, 2), UTM32)
    # Midway between the four centres -> mean; at a centre -> that value; near the edge -> clamped.
    assert g.lookup(1.0, 1.0, bilinear=True).rate_kg_ha == pytest.approx(15.0)
    assert g.lookup(0.5, 1.5, bilinear=True).rate_kg_ha == pytest.approx(0.0)
    assert g.lookup(0.75, 1.5, bilinear=True).rate_kg_ha == pytest.approx(2.5)
    assert g.lookup(0.1, 1.9, bilinear=True).rate_kg_ha == pytest.approx(0.0)
    g.rates_kg_ha[1, 1] = np.nan
    assert g.lookup(0.9, 1.1, bilinear=True).rate_kg_ha == pytest.approx(0.0)  # nearest cell's value


def meridian_arc_m(lat_deg):
    """WGS84 meridian arc length from the equator (Helmert's series), independent of pyproj."""
    a, f = 6378137.0, 1 / 298.257223563
    n = f / (2 - f)
    phi = math.radians(lat_deg)
    big_a = a / (1 + n) * (1 + n**2 / 4 + n**4 / 64)
    coef = [-3 / 2 * n + 9 / 16 * n**3, 15 / 16 * n**2 - 15 / 32 * n**4, -35 / 48 * n**3, 315 / 512 * n**4]
    return big_a * (phi + sum(c * math.sin(2 * (k + 1) * phi) for k, c in enumerate(coef)))


def test_wgs84_point_lands_in_right_utm_cell():
    # On UTM 32N's central meridian (9 E), easting is 500 000 m and northing k0 * meridian arc.
    lat = 48.123456
    northing = 0.9996 * meridian_arc_m(lat)
    g = grid_from_bounds((499_000, northing - 1000, 501_000, northing + 1000), 2.0, UTM32)
    g.rates_kg_ha[:] = np.arange(g.rates_kg_ha.size).reshape(g.rows, g.cols)
    res = g.lookup(9.0, lat, crs="EPSG:4326")
    assert (int(res.row), int(res.col)) == (int((g.bounds[3] - northing) // 2.0), 500)
    s = g.sample(lat=lat, lon=9.0)
    assert (s["row"], s["col"], s["inside"]) == (int(res.row), 500, True)
    assert s["rate_kg_ha"] == g.rates_kg_ha[s["row"], s["col"]]


def test_utm_crs_for():
    assert utm_crs_for(9.0, 48.0).to_epsg() == 32632
    assert utm_crs_for(-58.4, -34.6).to_epsg() == 32721
    assert utm_crs_for(180.0, 10.0).to_epsg() == 32660
    with pytest.raises(MapError, match="lon"):
        utm_crs_for(200.0, 0.0)


def test_sample_outside_and_nodata():
    g = small_grid()
    assert g.sample(x=0.0, y=0.0) == {"rate_kg_ha": None, "inside": False, "row": None, "col": None}
    assert g.sample(x=1025.0, y=2015.0) == {"rate_kg_ha": None, "inside": True, "row": 1, "col": 2}
    with pytest.raises(MapError, match="either lat and lon"):
        g.sample(lat=1.0, x=2.0)
    with pytest.raises(MapError, match="finite"):
        g.sample(x=float("inf"), y=1.0)


def test_info_keys_and_values():
    info = small_grid().info()
    assert info["crs"] == UTM32 and info["rows"] == 3 and info["cols"] == 4
    assert info["cell_size"] == [10.0, 10.0] and info["cell_size_unit"] == "metre"
    assert info["min_rate_kg_ha"] == 1.0 and info["max_rate_kg_ha"] == 12.0
    assert info["mean_rate_kg_ha"] == pytest.approx(71 / 11)
    assert info["nodata_share"] == pytest.approx(1 / 12)
    w, s, e, n = info["bounds_wgs84"]
    assert -180 < w < e < 180 and -90 < s < n < 90


def test_grid_validation():
    with pytest.raises(MapError, match="north-up"):
        Grid(np.ones((2, 2)), Affine(1, 0.1, 0, 0, -1, 0), UTM32)
    with pytest.raises(MapError, match="north-up"):
        Grid(np.ones((2, 2)), Affine(1, 0, 0, 0, 1, 0), UTM32)
    with pytest.raises(MapError, match="2-D"):
        Grid(np.ones(3), Affine(1, 0, 0, 0, -1, 0), UTM32)
    with pytest.raises(MapError, match="not a coordinate reference system"):
        Grid(np.ones((2, 2)), Affine(1, 0, 0, 0, -1, 0), "EPSG:999999")
    with pytest.raises(MapError, match="exceeds the cap"):
        grid_from_bounds((0, 0, 1e6, 1e6), 0.01, UTM32)


def test_reproject_wgs84_to_utm_keeps_values_and_sharp_edges():
    # Two zones in lon/lat, split at 9.0005 E; reprojected with nearest neighbour at 1 m.
    rates = np.full((20, 20), 100.0)
    rates[:, 10:] = 200.0
    g = Grid(rates, Affine(0.0001, 0, 8.9995, 0, -0.0001, 48.001), "EPSG:4326")
    u = g.reproject(UTM32, cell_size_m=1.0)
    assert u.crs.to_epsg() == 32632 and u.cell_size == (1.0, 1.0)
    assert set(np.unique(u.rates_kg_ha[~np.isnan(u.rates_kg_ha)])) == {100.0, 200.0}
    # Every UTM cell holds the lon/lat map's value at its centre.
    x, y = u.cell_centres()
    xx, yy = np.meshgrid(x, y)
    lon, lat = transform_xy(xx, yy, u.crs, g.crs)
    np.testing.assert_array_equal(g.lookup(lon, lat).rate_kg_ha, u.rates_kg_ha)
    back = u.reproject("EPSG:4326")
    assert back.crs.is_geographic


def test_reproject_continuous_map_bilinear_onto_finer_cells():
    from vrsim.maps import synthetic

    g = synthetic.random_field((500_000, 5_300_000, 500_400, 5_300_400), UTM32, cell_size_m=10, seed=4)
    u = g.reproject("EPSG:32633", cell_size_m=2.0)  # the next UTM zone: rotated and finer
    x, y = u.cell_centres()
    xx, yy = np.meshgrid(x, y)
    expected = g.lookup(xx, yy, crs=u.crs, bilinear=True).rate_kg_ha
    inner = ~np.isnan(u.rates_kg_ha)
    inner[:3], inner[-3:], inner[:, :3], inner[:, -3:] = False, False, False, False
    inside = g.lookup(xx, yy, crs=u.crs)
    # Away from the map's edge (where GDAL and vrsim clamp differently), GDAL's bilinear is vrsim's.
    sel = inner & (inside.row > 0) & (inside.row < g.rows - 1) & (inside.col > 0) & (inside.col < g.cols - 1)
    assert sel.sum() > 20_000
    np.testing.assert_allclose(u.rates_kg_ha[sel], expected[sel], rtol=2e-4)
    assert len(np.unique(u.rates_kg_ha[sel])) > 10 * len(np.unique(g.rates_kg_ha))  # not nearest


def test_reproject_continuous_map_averaged_onto_coarser_cells():
    from vrsim.maps import synthetic

    g = synthetic.random_field((500_000, 5_300_000, 500_200, 5_300_200), UTM32, cell_size_m=1, seed=5)
    g.rates_kg_ha[:40, :40] = np.nan  # nodata stays out of the averages
    c = g.reproject(UTM32, cell_size_m=5.0)
    assert (c.rows, c.cols) == (40, 40) and c.cell_size == (5.0, 5.0)
    blocks = g.rates_kg_ha.reshape(40, 5, 40, 5)
    counts = (~np.isnan(blocks)).sum(axis=(1, 3))
    expected = np.where(counts > 0, np.nansum(blocks, axis=(1, 3)) / np.maximum(counts, 1), np.nan)
    np.testing.assert_allclose(c.rates_kg_ha, expected, rtol=1e-9, equal_nan=True)
    assert np.isnan(c.rates_kg_ha[:8, :8]).all()


def test_reproject_zone_map_keeps_zone_rates_and_nodata():
    from vrsim.maps import synthetic

    g = synthetic.zones((500_000, 5_300_000, 500_300, 5_300_300), UTM32, cell_size_m=5, seed=2)
    g.rates_kg_ha[0, :] = np.nan
    w = g.reproject("EPSG:4326", cell_size_m=7.0)  # coarser, still nearest: zones stay zones
    assert set(np.unique(w.rates_kg_ha[~np.isnan(w.rates_kg_ha)])) <= set(np.unique(g.rates_kg_ha))
    assert np.isnan(w.rates_kg_ha).any() and w.quantity == "rate"


def test_check_overlap():
    g = small_grid()
    assert g.check_overlap((1000, 2000, 1040, 2030), UTM32) == pytest.approx(1.0)
    assert g.check_overlap(shapely.box(1020, 2000, 1060, 2030), UTM32) == pytest.approx(0.5)
    lon, lat = transform_xy(1020.0, 2015.0, g.crs, WGS84)
    inner = shapely.Point(float(lon), float(lat)).buffer(1e-5)
    assert g.check_overlap(inner, "EPSG:4326") == pytest.approx(1.0)
    with pytest.raises(MapError, match="do not overlap"):
        g.check_overlap((5000, 5000, 6000, 6000), UTM32)
    with pytest.raises(MapError, match="no area"):
        g.check_overlap((1000, 2000, 1000, 2000), UTM32)


@pytest.mark.parametrize("mode,expected,along", [
    ("off", [10.0, 0.0, 0.0], [0.0, 10.0, 0.0, 0.0, 20.0]),
    # hold along a sequence: the last known rate before each tick, else the one before the sequence
    ("hold", [10.0, 7.0, 7.0], [7.0, 10.0, 10.0, 10.0, 20.0]),
    ("default", [10.0, 3.0, 3.0], [3.0, 10.0, 3.0, 3.0, 20.0])])
def test_rate_policy(mode, expected, along):
    p = RatePolicy(mode, default_rate_kg_ha=3.0)
    assert p.apply(10.0, True, 7.0) == expected[0]
    assert p.apply(float("nan"), True, 7.0) == expected[1]  # nodata
    assert p.apply(10.0, False, 7.0) == expected[2]  # outside
    rate = np.array([np.nan, 10.0, np.nan, 10.0, 20.0])
    inside = np.array([True, True, True, False, True])
    arr = p.apply(rate, inside, 7.0)
    np.testing.assert_array_equal(arr, along)
    # The same as tick-by-tick calls that carry the last commanded rate over.
    last, ticks = 7.0, []
    for r, i in zip(rate, inside, strict=True):
        last = p.apply(float(r), bool(i), last)
        ticks.append(last)
    np.testing.assert_array_equal(arr, ticks)


def test_rate_policy_validation_and_hold_without_history():
    assert RatePolicy("hold").apply(float("nan"), False, None) == 0.0
    with pytest.raises(MapError, match="mode"):
        RatePolicy("maybe")
    with pytest.raises(MapError, match="default_rate_kg_ha"):
        RatePolicy("default", -1.0)
