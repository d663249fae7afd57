"""ISO 11783-10 TimeLogs: the real terminal export in ../shared/data/timelog, hand-made layouts,
damaged binaries, and vrsim's TASKDATA writer read back."""

import os
import shutil
import struct
import zipfile

import numpy as np
import pytest

from vrsim.common import MapError
from vrsim.maps.pointlog import PointLog
from vrsim.maps.taskdata import (
    _condensed_work_states,
    _parse_ddi,
    _sections_from_condensed,
    read_taskdata_log,
    write_taskdata,
)
from vrsim.maps.timelog import encode_records, header_xml, read_timelogs

START = np.datetime64("2026-05-04T10:00:00", "ms")


def valid_logs(shared_dir):
    return os.path.join(shared_dir, "data", "timelog", "isoxml-dotnet-ValidTimeLogs")


def test_shared_timelogs_known_values(shared_dir):
    logs = read_timelogs(valid_logs(shared_dir))
    assert len(logs) == 21
    first = logs[0]
    assert (first.name, first.task, first.records) == ("TLG00001", "TSK1", 4716)
    assert first.count(0x008D) == 4716  # actual work state, in every record
    assert first.count(0x0094) == 560  # total fuel consumption, on change
    assert str(first.time[1].astype("datetime64[D]")) == "2020-01-02"
    assert len(first.ddi) == 26 and first.element[0] == "DET-123456789"
    # The positions lie on the task's field (PFD-2, near 54.58 N 10.21 E), status "not available".
    assert np.all(np.abs(first.lat_deg - 54.58) < 0.01) and np.all(np.abs(first.lon_deg - 10.21) < 0.01)
    assert np.all(first.position["status"] == 15) and np.isnan(first.position["up_m"]).all()
    assert set(np.unique(first.value(0x008D))) == {0.0, 1.0}
    fuel = first.value(0x0094, hold=True)
    assert np.isfinite(fuel).sum() >= 560 and np.all(np.diff(fuel[np.isfinite(fuel)]) >= 0)  # a counter


def test_shared_timelogs_from_a_zip(shared_dir, tmp_path):
    src = valid_logs(shared_dir)
    with zipfile.ZipFile(tmp_path / "td.zip", "w") as z:
        for name in os.listdir(src):
            z.write(os.path.join(src, name), f"TASKDATA/{name}")
    logs = read_timelogs(tmp_path / "td.zip")
    assert [t.records for t in logs] == [t.records for t in read_timelogs(src)]


def copy_logs(shared_dir, tmp_path):
    dst = tmp_path / "td"
    shutil.copytree(valid_logs(shared_dir), dst)
    for p in dst.iterdir():
        p.chmod(0o644)
    return dst


@pytest.mark.parametrize("cut", [3, 81, 95])
def test_truncated_binary_names_file_and_record(shared_dir, tmp_path, cut):
    td = copy_logs(shared_dir, tmp_path)
    binary = td / "TLG00001.bin"
    data = binary.read_bytes()
    binary.write_bytes(data[:-cut])
    with pytest.raises(MapError, match=r"TLG00001\.BIN: record 471[45] \(byte \d+\) is truncated"):
        read_timelogs(td)


def test_binary_inconsistent_with_header(shared_dir, tmp_path):
    td = copy_logs(shared_dir, tmp_path)
    header = td / "TLG00001.xml"
    lines = header.read_text().splitlines()
    # Every one of the 26 DLVs has values; without the last one in the header, index 25 has no DLV.
    header.write_text("\n".join(line for line in lines if "EAE2" not in line))
    with pytest.raises(MapError, match=r"TLG00001\.BIN: record \d+ \(byte \d+\) has a value for DLV "
                                       r"index 25, but the header declares 25 DLVs"):
        read_timelogs(td)


def test_missing_and_bad_files(shared_dir, tmp_path):
    td = copy_logs(shared_dir, tmp_path)
    with pytest.raises(MapError, match=r"(?i)TLG00001\.BIN: [\d,]+ bytes is over the 100,000 bytes cap"):
        read_timelogs(td, max_bytes=100_000)
    (td / "TLG00002.bin").unlink()
    with pytest.raises(MapError, match=r"TLG00002\.BIN \(task TSK2\) is missing"):
        read_timelogs(td)
    (td / "TLG00001.xml").write_text("<TIM><PTN")
    with pytest.raises(MapError, match=r"TLG00001\.XML: not well-formed"):
        read_timelogs(td)
    (td / "TLG00001.xml").write_text('<TIM A="" D="4"><DLV A="zz" C="DET-1"/></TIM>')
    with pytest.raises(MapError, match="DLV 0.*A='zz' is not a valid hexadecimal DDI"):
        read_timelogs(td)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "TASKDATA.XML").write_text('<ISO11783_TaskData><TSK A="TSK1"/></ISO11783_TaskData>')
    with pytest.raises(MapError, match="no task .* references a TimeLog"):
        read_timelogs(tmp_path / "empty")


def hand_made(tmp_path, ptn: str, records: bytes, dlvs=("0007", "0043")):
    """A TASKDATA with one TimeLog whose header and binary are written by hand."""
    (tmp_path / "TASKDATA.XML").write_text('<ISO11783_TaskData VersionMajor="4"><TSK A="TSK9">'
                                           '<TLG A="TLG00007" C="1"/></TSK></ISO11783_TaskData>')
    dlv = "".join(f'<DLV A="{d}" B="" C="DET-1"/>' for d in dlvs)
    (tmp_path / "TLG00007.XML").write_text(f'<TIM A="" D="4">{ptn}{dlv}</TIM>')
    (tmp_path / "TLG00007.BIN").write_bytes(records)
    return read_timelogs(tmp_path)[0]


def test_constant_and_absent_position_fields(tmp_path):
    # Latitude constant in the header, longitude and altitude per record, no status.
    ptn = '<PTN A="48.125" B="" C=""/>'
    rec = [struct.pack("<IHii", 3_600_000 + 1000 * i, 16_000, 115_000_000 + i, 250_000 + i)
           + bytes([1, 1]) + struct.pack("<i", 10_000 + i) for i in range(3)]
    t = hand_made(tmp_path, ptn, b"".join(rec))
    assert t.records == 3
    np.testing.assert_array_equal(t.lat_deg, [48.125] * 3)
    np.testing.assert_allclose(t.lon_deg, [11.5, 11.5000001, 11.5000002])
    np.testing.assert_allclose(t.position["up_m"], [250.0, 250.001, 250.002])
    assert np.isnan(t.position["status"]).all()
    np.testing.assert_array_equal(t.value(0x43), [10_000, 10_001, 10_002])
    assert t.count(7) == 0 and np.isnan(t.value(7)).all()
    assert str(t.time[0]) == "2023-10-22T01:00:00.000"  # 16,000 days after 1980-01-01, 1 h
    np.testing.assert_array_equal(t.time_s, [0.0, 1.0, 2.0])


def test_no_position_and_variable_counts(tmp_path):
    # No PTN at all; records with 0, 2 and 1 values.
    recs = (struct.pack("<IH", 0, 1) + b"\x00"
            + struct.pack("<IH", 10, 1) + b"\x02" + b"\x00" + struct.pack("<i", -5) + b"\x01"
            + struct.pack("<i", 7)
            + struct.pack("<IH", 20, 1) + b"\x01" + b"\x01" + struct.pack("<i", 9))
    t = hand_made(tmp_path, "", recs)
    assert t.records == 3 and np.isnan(t.lat_deg).all()
    np.testing.assert_array_equal(t.value(7), [np.nan, -5, np.nan])
    np.testing.assert_array_equal(t.value(7, hold=True), [np.nan, -5, -5])
    np.testing.assert_array_equal(t.value(0x43), [np.nan, 7, 9])
    dup = struct.pack("<IH", 0, 1) + b"\x02" + (b"\x00" + struct.pack("<i", 1)) * 2
    with pytest.raises(MapError, match="record 0 .* logs one DLV twice"):
        hand_made(tmp_path, "", dup)


def test_column_lookup_errors(tmp_path):
    recs = struct.pack("<IH", 0, 1) + b"\x00"
    (tmp_path / "a").mkdir()
    t = hand_made(tmp_path / "a", "", recs, dlvs=("0007", "0007"))
    with pytest.raises(MapError, match="logs DDI 0007 on several device elements"):
        t.value(7)
    with pytest.raises(MapError, match="logs no DDI 0006; it logs DDI 0007"):
        t.value(6)


def test_encode_records_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    n, ddis = 200, [6, 7, 0x8D, 0x43]
    time = START + np.arange(n).astype("timedelta64[s]")
    lat = 48.0 + rng.uniform(0, 0.01, n)
    lon = 11.0 + rng.uniform(0, 0.01, n)
    lat[5] = np.nan  # no fix -> 0, 0
    values = rng.integers(-2**31, 2**31 - 1, (n, 4))
    logged = rng.random((n, 4)) < 0.6
    (tmp_path / "TASKDATA.XML").write_text('<ISO11783_TaskData><TSK A="T"><TLG A="TLG00001"/></TSK>'
                                           '</ISO11783_TaskData>')
    (tmp_path / "TLG00001.xml").write_bytes(header_xml(ddis, ["DET-2"] * 4))
    (tmp_path / "TLG00001.bin").write_bytes(encode_records(time, lat, lon, 4, values, logged))
    t = read_timelogs(tmp_path)[0]
    np.testing.assert_array_equal(t.time, time)
    np.testing.assert_array_equal(t.logged, logged)
    np.testing.assert_array_equal(t.values[logged], values[logged])
    fix = np.isfinite(lat)
    np.testing.assert_allclose(t.lat_deg[fix], lat[fix], atol=5e-8)
    assert t.lat_deg[5] == 0.0 and t.lon_deg[5] == 0.0
    assert np.all(t.position["status"] == 4)


def test_condensed_work_states():
    sections = np.array([[True, False, True], [False, False, False]])
    (word,) = _condensed_work_states(sections)
    # sections 1..3: 01 00 01, sections 4..16 not installed (11).
    expected = (0b01 | 0b00 << 2 | 0b01 << 4) | sum(3 << 2 * k for k in range(3, 16))
    assert word[0].view(np.uint32) == expected
    np.testing.assert_array_equal(_sections_from_condensed([word]), sections)
    many = np.random.default_rng(1).random((5, 40)) < 0.5
    words = _condensed_work_states(many)
    assert len(words) == 3
    np.testing.assert_array_equal(_sections_from_condensed(words), many)


def run_log(n=120, sections=6):
    t = np.arange(n, dtype=float)
    target = np.where(t < 60, 150.0, 210.0)
    applied = target + 3 * np.sin(t / 5)
    applied[:2] = np.nan
    on = np.ones((n, sections), dtype=bool)
    on[30:40, :2] = False
    return PointLog(600_000 + 2.0 * t, 5_340_000 + 0.5 * t, "EPSG:32632", applied=applied, target=target,
                    time_s=t, start=START, width_m=np.where(on.all(axis=1), 12.0, 8.0), work_on=t >= 2,
                    sections_on=on, gnss_status=8, heading_deg=76.0, speed_m_s=2.06)


def test_write_taskdata_round_trip(tmp_path):
    log = run_log()
    path = write_taskdata(log, tmp_path / "taskdata", [2.0] * 6)
    assert sorted(os.listdir(tmp_path / "taskdata")) == ["TASKDATA.XML", "TLG00001.bin", "TLG00001.xml"]
    t = read_timelogs(path)[0]
    assert list(t.ddi) == [6, 7, 0x8D, 0x43, 0xA1] and set(t.element) == {"DET-2"}
    assert t.count(7) == log.points - 2 and t.count(6) == log.points
    np.testing.assert_array_equal(t.value(6), np.rint(log.target * 100))  # mg/m^2
    back = read_taskdata_log(tmp_path / "taskdata")
    assert (back.unit, back.format, back.points) == ("kg/ha", "taskdata", log.points)
    np.testing.assert_allclose(back.applied, log.applied, atol=0.005, equal_nan=True)
    np.testing.assert_allclose(back.target, log.target, atol=0.005)
    np.testing.assert_array_equal(back.sections_on, log.sections_on)
    np.testing.assert_array_equal(back.work_on, log.work_on)
    np.testing.assert_allclose(back.width_m, log.width_m)
    np.testing.assert_array_equal(back.time_s, log.time_s)
    assert back.start == START and np.all(back.gnss_status == 8)
    lon, lat = log.lonlat()
    np.testing.assert_allclose(back.x, lon, atol=1e-7)
    np.testing.assert_allclose(back.y, lat, atol=1e-7)
    xml = (tmp_path / "taskdata" / "TASKDATA.XML").read_text()
    assert xml.count('C="4" D="section') == 6 and 'B="0087" C="-5000"' in xml  # section 1: 5 m left


def test_write_taskdata_refusals(tmp_path):
    log = run_log()
    write_taskdata(log, tmp_path / "a", [2.0] * 6)
    with pytest.raises(MapError, match="already holds a TASKDATA.XML"):
        write_taskdata(log, tmp_path / "a", [2.0] * 6)
    with pytest.raises(MapError, match="6 section columns but the implement 4 sections"):
        write_taskdata(log, tmp_path / "b", [3.0] * 4)
    with pytest.raises(MapError, match="folder .* does not exist"):
        write_taskdata(log, tmp_path / "no" / "c", [2.0] * 6)
    unitless = PointLog([0.0], [0.0], "EPSG:4326", applied=[1e4], target=[1e4], unit="", start=START,
                        time_s=[0.0])
    with pytest.raises(MapError, match="a TimeLog holds mass, volume or count rates, not 'no unit'"):
        write_taskdata(unitless, tmp_path / "d", [1.0])
    with pytest.raises(MapError, match="no start time"):
        write_taskdata(PointLog([0.0], [0.0], "EPSG:4326", [1.0], [1.0]), tmp_path / "e", [1.0])


def test_read_taskdata_log_chooses_ddis(shared_dir):
    with pytest.raises(MapError, match="no TimeLog logs an applied rate .*0094"):
        read_taskdata_log(valid_logs(shared_dir))
    # Any DDI can be read as the rate, in its own unit: here the work state (141) against nothing.
    log = read_taskdata_log(valid_logs(shared_dir), rate_ddi="141")
    assert log.unit == "" and log.points == 61314 and np.isnan(log.target).all()
    assert np.all(np.diff(log.time_s) >= 0)
    assert _parse_ddi("0x00A1") == 161 and _parse_ddi(7) == 7
    with pytest.raises(MapError, match="not a number"):
        _parse_ddi("seven")


def test_a_lone_timelog_is_read_from_its_header(shared_dir, tmp_path):
    """TLG00001.xml alone (its .bin beside it, no TASKDATA.XML): the known values of the terminal's log;
    where it logs no rate, the message says what it logs; vrsim's own TimeLog reads as its TASKDATA."""
    src = valid_logs(shared_dir)
    for name in ("TLG00001.xml", "TLG00001.bin"):
        shutil.copy(os.path.join(src, name), tmp_path / name)
    (t,) = read_timelogs(tmp_path / "TLG00001.xml")
    assert (t.records, t.count(0x8D), t.count(0x94), t.task) == (4716, 4716, 560, "")
    assert str(t.time[1]).startswith("2020-01-02")
    with pytest.raises(MapError, match="TLG00001.xml: no TimeLog logs an applied rate .*008D.*--rate-field"):
        read_taskdata_log(tmp_path / "TLG00001.xml")
    os.remove(tmp_path / "TLG00001.bin")
    with pytest.raises(MapError, match=r"TLG00001.xml: the TimeLog file TLG00001.BIN is missing beside it"):
        read_timelogs(tmp_path / "TLG00001.xml")
    path = write_taskdata(run_log(), tmp_path / "taskdata", [2.0] * 6)
    whole = read_taskdata_log(path)
    lone = read_taskdata_log(tmp_path / "taskdata" / "TLG00001.xml")
    for name in ("applied", "target", "time_s", "x", "y", "work_on", "sections_on"):
        np.testing.assert_array_equal(getattr(lone, name), getattr(whole, name))


def test_a_timelog_of_two_products_is_read_by_product(tmp_path):
    """DDI 6 and 7 logged on two bins (DET-3: PDT1 'Urea', DET-4: PDT2 'KAS', allocated by the task's
    PAN): refused without a product, listing both; read by id, name or element."""
    n = 5
    time = START + np.arange(n) * np.timedelta64(1, "s")
    values = np.tile([10_000, 9_900, 25_000, 25_500], (n, 1))
    folder = tmp_path / "TASKDATA"
    folder.mkdir()
    (folder / "TLG00001.xml").write_bytes(header_xml([6, 7, 6, 7], ["DET-3", "DET-3", "DET-4", "DET-4"]))
    (folder / "TLG00001.bin").write_bytes(encode_records(time, np.full(n, 52.0), np.full(n, 10.0), 4, values,
                                                         np.ones((n, 4), bool)))
    (folder / "TASKDATA.XML").write_text(
        '<?xml version="1.0"?><ISO11783_TaskData VersionMajor="4" VersionMinor="3" DataTransferOrigin="2">'
        '<TSK A="TSK1" G="4"><TLG A="TLG00001" C="1"/>'
        '<PAN A="PDT1" E="DET-3"/><PAN A="PDT2" E="DET-4"/></TSK>'
        '<PDT A="PDT1" B="Urea"/><PDT A="PDT2" B="KAS"/></ISO11783_TaskData>')
    with pytest.raises(MapError, match=r"logged on 2 device elements.*DET-3 \(PDT1 'Urea'\), DET-4 \(PDT2 "
                                       r"'KAS'\); choose one with --product"):
        read_taskdata_log(folder)
    for product, applied, target in (("PDT2", 255.0, 250.0), ("urea", 99.0, 100.0), ("DET-4", 255.0, 250.0)):
        log = read_taskdata_log(folder, product=product)
        assert (log.applied == applied).all() and (log.target == target).all(), product
    with pytest.raises(MapError, match="no product 'PDT3' logs DDI 0007; logged on: DET-3 \\(PDT1 'Urea'\\)"):
        read_taskdata_log(folder, product="PDT3")


def test_a_volume_rate_log_is_written_as_ddi_1_and_2_and_read_back_in_l_ha(tmp_path):
    gal = PointLog([0.0, 1e-5], [0.0, 0.0], "EPSG:4326", applied=[10.0, 12.0], target=[10.0, 10.0],
                   unit="gal/ac", start=START, time_s=[0.0, 1.0])
    write_taskdata(gal, tmp_path / "t", [1.0])
    xml = (tmp_path / "t" / "TASKDATA.XML").read_text()
    assert 'B="0001"' in xml and 'B="0002"' in xml and 'B="0007"' not in xml and 'E="L/ha"' in xml
    back = read_taskdata_log(tmp_path / "t")
    assert back.unit == "L/ha"
    np.testing.assert_allclose(back.in_unit("gal/ac").applied, [10.0, 12.0], rtol=1e-4)


def test_a_count_rate_log_is_written_as_ddi_11_and_12_and_read_back_in_seeds_ha(tmp_path):
    seeds = PointLog([0.0, 1e-5], [0.0, 0.0], "EPSG:4326", applied=[32000.0, 30000.0], target=[32000.0] * 2,
                     unit="seeds/ac", start=START, time_s=[0.0, 1.0])
    write_taskdata(seeds, tmp_path / "t", [1.0])
    xml = (tmp_path / "t" / "TASKDATA.XML").read_text()
    assert 'B="000B"' in xml and 'B="000C"' in xml and 'B="0007"' not in xml and 'E="seeds/ha"' in xml
    back = read_taskdata_log(tmp_path / "t")
    assert back.unit == "seeds/ha"   # DDI 11 and 12 count 0.001 seeds/m^2: 10 seeds/ha
    np.testing.assert_allclose(back.in_unit("seeds/ac").applied, [32000.0, 30000.0], atol=10 / 2.47)
