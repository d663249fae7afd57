"""As-applied point logs: the John Deere export in ../shared/data/asapplied, vrsim's GeoPackage and
zipped-shapefile exports read back, user-named fields and bad input."""

import os
import zipfile

import numpy as np
import pyogrio
import pytest

from vrsim.common import MapError
from vrsim.maps import MapWarning
from vrsim.maps.pointlog import PointLog, _deere_unit, convert_rate, read_point_log
from vrsim.maps.pointlog_write import write_points

START = np.datetime64("2026-05-04T10:00:00.250", "ms")


def deere(shared_dir):
    return os.path.join(shared_dir, "data", "asapplied", "jd-gen4-application-point-onehertz.zip")


def test_deere_export_known_values(shared_dir):
    log = read_point_log(deere(shared_dir))
    assert (log.points, log.unit, log.format) == (780, "gal/ac", "shapefile")
    assert log.crs.to_epsg() == 4326
    assert str(log.start) == "2017-11-29T16:21:32.193"  # from IsoTime, with its milliseconds
    assert log.time_s[1] == pytest.approx(0.992) and log.time_s[-1] == pytest.approx(779.011)
    assert np.isfinite(log.applied).all() and np.isfinite(log.target).all()
    assert log.applied[:3] == pytest.approx([24.21185872, 17.53553926, 13.52511496])
    assert log.target[0] == pytest.approx(9.99577053)
    assert log.width_m[0] == pytest.approx(121.25 * 0.3048)  # SWATHWIDTH in ft, per the metadata
    assert log.heading_deg[0] == pytest.approx(359.99985201)
    lon, lat = log.lonlat()
    assert -93.49 < lon.min() < lon.max() < -93.486 and 41.759 < lat.min() < lat.max() < 41.773


def test_deere_export_unzipped_and_user_fields(shared_dir, tmp_path):
    with zipfile.ZipFile(deere(shared_dir)) as z:
        z.extractall(tmp_path)
    shp = next(p for p in tmp_path.iterdir() if p.suffix == ".shp")
    log = read_point_log(shp, rate_field="TargetRate", target_field="AppliedRate", time_field="Time")
    assert log.unit == "gal/ac" and log.applied[0] == pytest.approx(9.99577053)
    assert str(log.start) == "2017-11-29T16:21:32.000"  # Deere's Time has whole seconds
    with pytest.raises(MapError, match="no attribute 'Rate' .*AppliedRate"):
        read_point_log(shp, rate_field="Rate")
    for p in tmp_path.iterdir():
        if p.name.endswith("Metadata.json"):
            p.unlink()
    with pytest.warns(MapWarning, match="does not say the unit"):
        assert read_point_log(shp).unit == ""
    assert read_point_log(shp, unit="gal/ac").unit == "gal/ac"


def run_log(n=50):
    t = np.arange(n, dtype=float)
    on = np.ones((n, 4), dtype=bool)
    on[10:20, 0] = False
    applied = 150 + np.cos(t)
    applied[7] = np.nan
    x = 600_000 + 2.0 * t
    x[3] = np.nan  # no position: cannot be placed
    return PointLog(x, 5_340_000 + 0.0 * t, "EPSG:32632", applied=applied, target=np.full(n, 150.0),
                    time_s=t, start=START, heading_deg=90.0, speed_m_s=2.0, width_m=12.0, sections_on=on,
                    gnss_status=8)


@pytest.mark.parametrize("name", ["as_applied_points.gpkg", "as_applied_points.zip"])
def test_export_round_trip(tmp_path, name):
    log = run_log()
    write_points(log, tmp_path / name)
    back = read_point_log(tmp_path / name)
    keep = np.isfinite(log.x)
    assert back.points == log.points - 1 and back.crs.to_epsg() == 4326 and back.unit == "kg/ha"
    assert back.start == START
    np.testing.assert_allclose(back.time_s, log.time_s[keep] - 0.0)
    np.testing.assert_array_equal(back.applied, log.applied[keep])
    np.testing.assert_array_equal(back.target, log.target[keep])
    np.testing.assert_array_equal(back.heading_deg, 90.0)
    np.testing.assert_array_equal(back.speed_m_s, 2.0)
    np.testing.assert_array_equal(back.width_m, 12.0)
    lon, lat = log.lonlat()
    np.testing.assert_allclose(back.x, lon[keep], atol=1e-9)
    np.testing.assert_allclose(back.y, lat[keep], atol=1e-9)
    fields = pyogrio.read_info(str(tmp_path / name))
    assert fields["crs"] == "EPSG:4326" and fields["geometry_type"] == "Point"
    types = dict(zip(fields["fields"], fields["ogr_types"], strict=True))
    assert types["time"] == ("OFTDateTime" if name.endswith(".gpkg") else "OFTString")
    assert types["sections"] == "OFTInteger"
    _, _, _, columns = pyogrio.raw.read(str(tmp_path / name), columns=["sections", "gnss"])
    assert columns[0][8] == 4 and columns[0][9] == 3 and set(columns[1]) == {8}  # record 3 left out


def test_export_refusals(tmp_path):
    with pytest.raises(MapError, match="written as .gpkg"):
        write_points(run_log(), tmp_path / "a.shp")
    with pytest.raises(MapError, match="does not exist"):
        write_points(run_log(), tmp_path / "no" / "a.gpkg")
    write_points(run_log(), tmp_path / "a.gpkg")
    write_points(run_log(10), tmp_path / "a.gpkg")  # replaces, does not add a layer
    assert pyogrio.read_info(str(tmp_path / "a.gpkg"))["features"] == 9


def test_read_refusals(tmp_path):
    import shapely

    polys = shapely.to_wkb(np.array([shapely.box(0, 0, 1, 1)]))
    pyogrio.raw.write(str(tmp_path / "zones.gpkg"), polys, [np.array([1.0]), np.array([1.0])],
                      ["applied", "target"], driver="GPKG", geometry_type="Polygon", crs="EPSG:32632")
    with pytest.raises(MapError, match="record 0 has Polygon geometry, not a point"):
        read_point_log(tmp_path / "zones.gpkg")
    pts = shapely.to_wkb(np.array([shapely.Point(0, 0)]))
    pyogrio.raw.write(str(tmp_path / "p.gpkg"), pts, [np.array([1.0])], ["rate"], driver="GPKG",
                      geometry_type="Point", crs="EPSG:32632")
    with pytest.raises(MapError, match="which attribute is the applied rate; attributes: \\['rate'\\]"):
        read_point_log(tmp_path / "p.gpkg")
    (tmp_path / "x.txt").write_text("x")
    with pytest.raises(MapError, match="must be a TASKDATA, a point shapefile"):
        read_point_log(tmp_path / "x.txt")
    (tmp_path / "bad.gpkg").write_text("not a geopackage")
    with pytest.raises(MapError, match="cannot read as a vector file"):
        read_point_log(tmp_path / "bad.gpkg")


def test_units():
    assert _deere_unit("gal1ac-1") == "gal/ac" and _deere_unit("kg1ha-1") == "kg/ha"
    assert _deere_unit("ft") == "ft" and _deere_unit("m2s-2") == "m^2/s^2"
    assert convert_rate([1.0], "lb/ac", "kg/ha")[0] == pytest.approx(1.12085, rel=1e-5)
    assert convert_rate([10.0], "gal/ac", "L/ha")[0] == pytest.approx(93.5396, rel=1e-5)
    with pytest.raises(MapError, match="without the product's density"):
        convert_rate([1.0], "gal/ac", "kg/ha")
    with pytest.raises(MapError, match="'bales/ac' is not a unit pint reads"):
        convert_rate([1.0], "bales/ac", "kg/ha")
    with pytest.raises(MapError, match="a volume rate \\(bushel/ac\\) to a mass rate"):
        convert_rate([1.0], "bushel/ac", "kg/ha")
    with pytest.raises(MapError, match="applied has shape \\(2,\\), the log has 3 points"):
        PointLog([0, 1, 2], [0, 1, 2], "EPSG:4326", applied=[1.0, 2.0], target=1.0)


def test_thin_to_one_hertz():
    t = np.arange(0, 10, 0.05)  # 20 Hz ticks
    log = PointLog(t, t, "EPSG:32632", applied=t, target=t, time_s=t, sections_on=np.ones((t.size, 3), bool))
    one = log.thin(1.0)
    np.testing.assert_allclose(one.time_s, np.arange(10.0), atol=1e-9)
    assert one.points == 10 and one.sections_on.shape == (10, 3) and one.applied[3] == one.time_s[3]
    ticks = np.arange(1, 201) * 0.05  # as a run's ticks: 0.15 / 0.05 rounds below 3
    run = PointLog(ticks, ticks, "EPSG:32632", applied=ticks, target=ticks, time_s=ticks)
    assert run.thin(0.05).points == ticks.size  # at the ticks' own rate: every tick
    with pytest.raises(MapError, match="period_s=0 must be a positive number"):
        log.thin(0)
