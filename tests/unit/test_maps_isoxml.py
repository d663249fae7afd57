"""ISOXML TASKDATA grids: the real files in ../shared/data/isoxml, round trips, and bad input."""

import os
import shutil
import warnings
import zipfile
from dataclasses import replace

import numpy as np
import pytest
from affine import Affine

from vrsim.common import MapError
from vrsim.maps import Grid, MapWarning, read_map, write_map

DOTNET = (55.82481700900832, 39.138728173503324, 0.0000902618210782717, 0.00016294086058760767)
XFARM = (56.42601949235737, 9.925274835877255, 0.00009028027270540372, 0.00016434866866111552)


def isoxml(shared_dir, name):
    return os.path.join(shared_dir, "data", "isoxml", name)


def centre(corner, row_from_south, col):
    a, b, c, d = corner
    return a + (row_from_south + 0.5) * c, b + (col + 0.5) * d


def test_type2_dotnet_reads_ddi6_layer_and_warns_on_wrong_filelength(shared_dir):
    with pytest.warns(MapWarning, match="Filelength"):
        g = read_map(isoxml(shared_dir, "isoxml-dotnet-Type2/TASKDATA.XML"))
    assert (g.rows, g.cols, g.format) == (10, 10, "isoxml")
    assert g.crs.to_epsg() == 4326
    west, south, east, north = g.bounds
    assert (south, west) == (DOTNET[0], DOTNET[1])
    assert north == pytest.approx(DOTNET[0] + 10 * DOTNET[2])
    for row, col, raw in [(0, 0, 1086161), (3, 4, 1699791), (9, 9, 488474)]:
        lat, lon = centre(DOTNET, row, col)
        s = g.sample(lat=lat, lon=lon)
        assert s["rate_kg_ha"] == pytest.approx(raw * 0.01, rel=1e-12)
        assert (s["row"], s["col"]) == (9 - row, col)  # vrsim's row 0 is the north row


def test_type2_xfarm_zip_and_folder(shared_dir, tmp_path):
    zpath = isoxml(shared_dir, "isoxml-js-task_with_grid.zip")
    g = read_map(zpath)
    zipfile.ZipFile(zpath).extractall(tmp_path)
    h = read_map(tmp_path / "TASKDATA")  # the folder
    np.testing.assert_array_equal(g.rates_kg_ha, h.rates_kg_ha)
    assert (g.rows, g.cols) == (54, 54)
    for row, col, raw in [(20, 30, 300220), (10, 40, 301900), (0, 0, 0)]:
        lat, lon = centre(XFARM, row, col)
        assert g.sample(lat=lat, lon=lon)["rate_kg_ha"] == pytest.approx(raw * 0.01)
    assert g.sample(lat=10.0, lon=10.0)["inside"] is False


def test_xfarm_field_boundary_does_not_overlap_grid(shared_dir):
    # The export's PFD polygon lies near Moscow, its grid in Denmark: the check must catch it.
    import defusedxml.ElementTree as DET
    import shapely

    z = zipfile.ZipFile(isoxml(shared_dir, "isoxml-js-task_with_grid.zip"))
    root = DET.fromstring(z.read("TASKDATA/TASKDATA.XML"))
    ring = [(float(p.get("D")), float(p.get("C"))) for p in root.iter("PNT")]
    g = read_map(isoxml(shared_dir, "isoxml-js-task_with_grid.zip"))
    with pytest.raises(MapError, match="do not overlap"):
        g.check_overlap(shapely.Polygon(ring), "EPSG:4326")


def test_type1_undefined_zones_are_nodata_with_warning(shared_dir):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = read_map(isoxml(shared_dir, "isoxml-dotnet-Type1/TASKDATA.XML"))
    assert any("treatment zones" in str(w.message) for w in caught)
    codes = np.fromfile(isoxml(shared_dir, "isoxml-dotnet-Type1/GRD00001.bin"), np.uint8)
    codes = codes.reshape(10, 10)[::-1]
    # Zones 0 and 1 are defined with rate 0; the other codes the cells name are undefined -> NaN.
    np.testing.assert_array_equal(np.isnan(g.rates_kg_ha), codes > 1)
    assert (g.rates_kg_ha[codes <= 1] == 0).all()


@pytest.mark.parametrize("name,match", [
    ("isoxml-dotnet-Type1_Invalid/TASKDATA.XML", "has 32 bytes but the declared grid"),
    ("isoxml-dotnet-Type2_Invalid/TASKDATA.XML", "has 1,200 bytes but the declared grid"),
    ("isoxml-js-grid-without-binary.zip", "GRD00001.BIN .* is missing"),
])
def test_real_invalid_files_refused(shared_dir, name, match):
    with pytest.raises(MapError, match=match):
        read_map(isoxml(shared_dir, name))


def wgs84_grid(rates):
    transform = Affine(0.0002, 0, 9.9, 0, -0.0001, 56.4)
    return Grid(np.asarray(rates, float), transform, "EPSG:4326", product="Urea")


@pytest.mark.parametrize("name", ["TASKDATA.XML", "rx.zip"])
def test_write_read_round_trip(tmp_path, name):
    rng = np.random.default_rng(3)
    g = wgs84_grid(np.round(rng.uniform(0, 400, (7, 9)), 2))
    write_map(g, tmp_path / name)
    back = read_map(tmp_path / name)
    np.testing.assert_allclose(back.rates_kg_ha, g.rates_kg_ha, rtol=0, atol=1e-9)
    assert back.transform.almost_equals(g.transform, precision=1e-12)
    assert back.product == "Urea"
    if name.endswith(".xml") or name.endswith(".XML"):
        assert (tmp_path / "GRD00001.BIN").stat().st_size == 7 * 9 * 4


def test_write_never_overwrites_and_needs_a_folder(tmp_path):
    g = wgs84_grid(np.full((3, 4), 150.0))
    (tmp_path / "a").mkdir()
    write_map(g, tmp_path / "a" / "TASKDATA.XML")
    with pytest.raises(MapError, match="already holds a TASKDATA.XML; vrsim does not overwrite"):
        write_map(g, tmp_path / "a" / "TASKDATA.XML")
    with pytest.raises(MapError, match="already holds a TASKDATA.XML"):
        write_map(g, tmp_path / "a")  # the folder itself
    assert (tmp_path / "a" / "GRD00001.BIN").stat().st_size == 3 * 4 * 4
    # A folder with another export's grid file but no TASKDATA.XML: the next free GRD name.
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "GRD00001.bin").write_bytes(b"another export")
    write_map(g, tmp_path / "b")
    assert (tmp_path / "b" / "GRD00001.bin").read_bytes() == b"another export"
    assert 'G="GRD00002"' in (tmp_path / "b" / "TASKDATA.XML").read_text()
    np.testing.assert_array_equal(read_map(tmp_path / "b").rates_kg_ha, g.rates_kg_ha)
    # A new folder is made; other .xml names are not TASKDATA.
    write_map(g, tmp_path / "c")
    assert read_map(tmp_path / "c" / "TASKDATA.XML").rows == 3
    with pytest.raises(MapError, match="written as a TASKDATA folder: .* not a.xml"):
        write_map(g, tmp_path / "a.xml")
    assert not (tmp_path / "GRD00001.BIN").exists()
    # An error map (differences) or a map in another unit is no prescription.
    for other, needle in ((replace(g, quantity="difference"), "differences of rates in kg/ha"),
                          (replace(g, unit="gal/ac", map_unit=None), "holds rates in gal/ac")):
        with pytest.raises(MapError, match=f"ISOXML prescription holds rates in kg/ha; .*{needle}"):
            write_map(other, tmp_path / "d")


def test_write_utm_grid_reprojects_to_wgs84(tmp_path):
    rates = np.full((10, 10), 120.0)
    rates[:, 5:] = 80.0
    g = Grid(rates, Affine(5, 0, 500_000, 0, -5, 5_300_050), "EPSG:32632")
    write_map(g, tmp_path / "TASKDATA.XML")
    back = read_map(tmp_path / "TASKDATA.XML")
    assert back.crs.to_epsg() == 4326
    # Points well inside each half (away from the zone edge by > one cell) keep their rate.
    x = np.array([500_007.0, 500_012.0, 500_038.0, 500_043.0])
    y = np.array([5_300_040.0, 5_300_010.0, 5_300_040.0, 5_300_010.0])
    np.testing.assert_array_equal(back.lookup(x, y, crs="EPSG:32632").rate_kg_ha, [120, 120, 80, 80])


ZONE6 = '<TZN A="1"><PDV A="0006" B="0"/></TZN>'


def write_taskdata(folder, grd_attrs, tzn=ZONE6, binary=b"", head=""):
    folder.mkdir(exist_ok=True)
    attrs = {"A": "50.0", "B": "8.0", "C": "0.0001", "D": "0.0001", "E": "2", "F": "2", "G": "GRD00001",
             "I": "2", "J": "1"}
    attrs.update(grd_attrs)
    grd = " ".join(f'{k}="{v}"' for k, v in attrs.items() if v is not None)
    xml = (f'<?xml version="1.0" encoding="utf-8"?>{head}<ISO11783_TaskData VersionMajor="4" '
           f'VersionMinor="2"><TSK A="TSK1">{tzn}<GRD {grd}/></TSK></ISO11783_TaskData>')
    (folder / "TASKDATA.XML").write_text(xml)
    if binary is not None:
        (folder / "GRD00001.BIN").write_bytes(binary)
    return str(folder / "TASKDATA.XML")


def le32(values):
    return np.asarray(values, "<i4").tobytes()


def test_synthetic_type2_orientation(tmp_path):
    # File order: row 0 is the south row, cells run east.
    path = write_taskdata(tmp_path / "t", {}, binary=le32([100, 200, 300, 400]))
    g = read_map(path)
    np.testing.assert_allclose(g.rates_kg_ha, [[3.0, 4.0], [1.0, 2.0]])


@pytest.mark.parametrize("grd,tzn,binary,match", [
    ({}, None, le32([1, 2, 3]), "truncated"),
    ({}, None, le32([1, 2, 3, 4, 5]), "oversized"),
    ({"E": "100000", "F": "100000"}, None, b"", "exceeds the cap"),
    ({}, None, le32([1, -2, 3, 4]), "negative rate"),
    ({}, '<TZN A="1"><PDV A="000B" B="0"/></TZN>', le32([1, 2, 3, 4]),
     "DDI 000B .*needs DDI 0006 .* or 0001"),
    ({}, '<TZN A="1"><PDV A="00ZZ" B="0"/></TZN>', le32([1, 2, 3, 4]), "not a valid hexadecimal DDI"),
    ({"I": "3"}, None, le32([1, 2, 3, 4]), "grid type must be 1 or 2"),
    ({"J": "7"}, None, le32([1, 2, 3, 4]), "defined treatment zone"),
    ({"C": "5"}, None, le32([1, 2, 3, 4]), "cell size"),
    ({"A": "abc"}, None, le32([1, 2, 3, 4]), "A='abc' is not a valid float"),
    ({"E": None}, None, le32([1, 2, 3, 4]), "no attribute E"),
    ({"I": "1"}, '<TZN A="1"><PDV A="0006" B="-5"/></TZN>', bytes([1, 1, 1, 1]), "negative rate"),
    ({"I": "1"}, '<TZN A="1"><PDV A="000B" B="5"/></TZN>', bytes([1, 1, 1, 1]),
     "the treatment zones hold DDI 000B"),
    ({}, None, None, "is missing"),
])
def test_bad_taskdata_refused(tmp_path, grd, tzn, binary, match):
    kwargs = {"binary": binary} if tzn is None else {"tzn": tzn, "binary": binary}
    path = write_taskdata(tmp_path / "t", grd, **kwargs)
    with pytest.raises(MapError, match=match):
        read_map(path)


def test_max_cells_can_be_raised(tmp_path):
    path = write_taskdata(tmp_path / "t", {}, binary=le32([1, 2, 3, 4]))
    with pytest.raises(MapError, match="exceeds the cap"):
        read_map(path, max_cells=3)
    assert read_map(path, max_cells=4).rows == 2


def test_hostile_and_malformed_xml_refused(tmp_path):
    laughs = '<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;">]>'
    path = write_taskdata(tmp_path / "a", {"G": "&lol2;"}, binary=le32([1, 2, 3, 4]), head=laughs)
    with pytest.raises(MapError, match="refused"):
        read_map(path)
    external = '<!DOCTYPE x [<!ENTITY ext SYSTEM "file:///etc/passwd">]>'
    path = write_taskdata(tmp_path / "b", {"G": "&ext;"}, binary=le32([1, 2, 3, 4]), head=external)
    with pytest.raises(MapError, match="refused"):
        read_map(path)
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "TASKDATA.XML").write_text("<ISO11783_TaskData><TSK>")
    with pytest.raises(MapError, match="not well-formed"):
        read_map(tmp_path / "c" / "TASKDATA.XML")
    (tmp_path / "c" / "TASKDATA.XML").write_text("<Other/>")
    with pytest.raises(MapError, match="root element"):
        read_map(tmp_path / "c" / "TASKDATA.XML")


def test_zip_without_taskdata_refused(tmp_path, shared_dir):
    with zipfile.ZipFile(tmp_path / "x.zip", "w") as z:
        z.writestr("readme.txt", "nothing")
    with pytest.raises(MapError, match="neither a TASKDATA.XML nor a .shp"):
        read_map(tmp_path / "x.zip")
    shutil.copy(isoxml(shared_dir, "isoxml-dotnet-Type2/TASKDATA.XML"), tmp_path / "TASKDATA.XML")
    with pytest.raises(MapError, match="missing"):
        read_map(tmp_path / "TASKDATA.XML")
