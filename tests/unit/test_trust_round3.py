"""Trust, third round (issue 41): input whose cost grew without bound, each refused with one line:
unit strings pint's parser would evaluate (``9**9**9 kg/ha`` never returned), TOML whose dotted keys
make tomllib quadratic, a catch-tray CSV of millions of rows, a TimeLog whose header makes its decoded
arrays 36 times its size; and three smaller holes: a sweep's ``--out`` that cannot be written, KMZ
files capped as 1 MB, an ``.aux.xml`` naming a file through character references."""

from __future__ import annotations

import glob
import os
import subprocess
import tomllib
import zipfile

import numpy as np
import pytest
import rasterio
from affine import Affine

from tests.conftest import ROOT, VRSIM
from vrsim.common import ControllerError, MapError, ScenarioError, VehicleError, files, toml_text
from vrsim.controller.kinds.fuzzy_pid import _load_rules
from vrsim.maps import units
from vrsim.maps.timelog import read_timelogs
from vrsim.maps.units import MAX_UNIT_CHARS, convert_rate, rate_unit
from vrsim.services.outputs.sweep_results import ResultsTable
from vrsim.services.sim import scenario
from vrsim.services.sim.compare import _spec_table
from vrsim.services.sim.overrides import machine_overrides
from vrsim.services.sim.sweep.design import parse_sweep
from vrsim.vehicle.field import Field
from vrsim.vehicle.spinner import MAX_PROFILE_LINE, MAX_PROFILE_ROWS, SpinnerSpec

FIELD = '[field]\nrectangle = { width_m = 36.0, length_m = 60.0, lat = 52.1, lon = 11.6 }\n'


class NeverReached:
    """A stand-in for `what` (pint's registry, tomllib) that keeps its calls and fails them: the refusals
    below come before it, where its cost grew without bound (``9**9**9`` never returned; tomllib took
    34.7 s on a 300 KB dotted header). A caller that swallows the failure still leaves ``calls``."""

    def __init__(self, what: str):
        self.what, self.calls = what, []

    def __call__(self, *args, **kwargs):
        self.calls.append(args)
        raise AssertionError(f"{self.what} was reached with {str(args)[:80]}")


def one_line_exit_2(p: subprocess.CompletedProcess, *needles: str) -> str:
    err = p.stderr.decode() if isinstance(p.stderr, bytes) else p.stderr
    assert p.returncode == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert all(n in err for n in needles), err
    return err


# ------------------------------------------------------------------------------------------ units
EVALUATED = ["9**9**9 kg/ha", "10**10**10 kg/ha", "__import__('os').system('true')", "k" * 10_240,
             "kg/ha" + " " * 100, "(kg)/ha", "kg/ha**999", "m^100/ha", "9^9 kg/ha", "kg/ha; true"]


@pytest.mark.parametrize("text", EVALUATED, ids=lambda t: t[:20])
def test_unit_strings_outside_the_grammar_are_refused_before_pint(text, monkeypatch):
    pint = NeverReached("pint's unit registry")
    monkeypatch.setattr(units, "_registry", pint)
    with pytest.raises(MapError) as err:
        rate_unit(text, "s.toml: [map] unit")
    message = str(err.value)
    assert pint.calls == []
    assert message.startswith("s.toml: [map] unit: ") and "\n" not in message
    assert "is not a unit vrsim reads" in message and len(message) < 400  # the value shortened


@pytest.mark.parametrize("text, kg_ha", [
    ("kg/ha", 1.0), ("kg ha-1", 1.0), ("kg.ha-1", 1.0), ("kg ha^-1", 1.0), ("kg*ha**-1", 1.0),
    ("kg / ha", 1.0), ("kg·ha⁻¹", 1.0), ("lb/ac", 0.45359237 / 0.40468564224), ("lbs/ac", None),
    ("t/ha", 1000.0), ("kg m-2", 10_000.0), ("kg/m²", 10_000.0), ("mg/m^2", 0.01), ("mg m**-2", 0.01),
    ("g/m2", 10.0), ("L/ha", None), ("gal/ac", None), ("floz/ac", None), ("µL/m2", None),
    ("seeds/ha", None), ("1/ha", None), ("gallon/acre", None)])
def test_real_spellings_keep_reading(text, kg_ha):
    unit = rate_unit(text)
    if kg_ha is not None:
        assert convert_rate(1.0, unit, "kg/ha") == pytest.approx(kg_ha, rel=1e-9)


def test_a_unit_of_the_grammar_pint_cannot_read_is_still_one_line():
    for text in ("furlongs of rate", "m**0*%", "gal1ac-1", "x" * MAX_UNIT_CHARS):
        with pytest.raises(MapError, match=r"^u: .* is not a (unit pint reads|unit vrsim reads|rate)"):
            rate_unit(text, "u")


@pytest.mark.parametrize("text", EVALUATED[:4], ids=lambda t: t[:20])
def test_a_scenarios_map_unit_is_refused_naming_the_key(text, monkeypatch):
    toml = f'{FIELD}[map]\nfile = "rx.tif"\nunit = "{text}"\n'
    pint = NeverReached("pint's unit registry")
    monkeypatch.setattr(units, "_registry", pint)
    with pytest.raises(ScenarioError) as err:
        scenario.parse(toml, "s.toml")
    assert pint.calls == []
    assert str(err.value).startswith("s.toml: [map] unit: ") and len(str(err.value)) < 400


def _tif(path, band_unit):
    with rasterio.open(path, "w", driver="GTiff", width=2, height=1, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(10, 0, 500_000, 0, -10, 5_300_000)) as dst:
        dst.write(np.array([[100.0, 200.0]], np.float32), 1)
        dst.set_band_unit(1, band_unit)
    return path


def test_map_info_on_a_geotiff_whose_band_unit_is_an_expression_says_so_without_evaluating_it(tmp_path):
    """The expression is refused by the unit parser, not evaluated: the info describes the values as
    stored and says why the unit does not read."""
    path = _tif(tmp_path / "rx.tif", "9**9**9 kg/ha")
    p = subprocess.run([VRSIM, "map", "info", str(path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and "band unit: '9**9**9 kg/ha' is not a unit vrsim reads" in p.stdout, p


def test_run_with_a_map_unit_that_is_an_expression_exits_2(tmp_path):
    _tif(tmp_path / "rx.tif", "kg/ha")
    path = tmp_path / "s.toml"
    path.write_text(f'{FIELD}[map]\nfile = "rx.tif"\nunit = "10**10**10 kg/ha"\n')
    p = subprocess.run([VRSIM, "run", str(path), "--check"], capture_output=True, text=True, timeout=60)
    one_line_exit_2(p, "[map] unit: '10**10**10 kg/ha' is not a unit vrsim reads")


# ------------------------------------------------------------------------------------------- TOML
WORST = {
    "a dotted header of 300 KB": ("[" + ".".join(["a"] * 150_000) + "]\n", "a dotted key of over 16 parts"),
    "a dotted key of 300 KB": (".".join(["a"] * 150_000) + " = 1\n", "a dotted key of over 16 parts"),
    "quoted parts": (".".join(['"a"'] * 75_000) + " = 1\n", "a dotted key of over 16 parts"),
    "300 tables": ("".join(f"[t{i}]\nx = 1\n" for i in range(300)), "over 256 tables"),
    "300 dotted keys": ("".join(f"t{i}.x = 1\n" for i in range(300)), "over 256 tables"),
    "arrays 5,000 deep": ("x = " + "[" * 5000 + "]" * 5000 + "\n", "values nested too deeply"),
    "inline tables 20 deep": ("x = " + "{a = " * 20 + "1" + "}" * 20 + "\n", "values nested too deeply"),
}


@pytest.mark.parametrize("case", WORST)
def test_toml_that_would_make_tomllib_quadratic_is_refused_by_the_scan(case, monkeypatch):
    text, needle = WORST[case]
    loads = NeverReached("tomllib.loads")
    monkeypatch.setattr(tomllib, "loads", loads)  # before the scan: 34.7 s for the 300 KB header
    with pytest.raises(ScenarioError) as err:
        scenario.parse(text, "s.toml")
    assert loads.calls == []
    assert str(err.value).startswith("s.toml: not a scenario: ") and needle in str(err.value)


def test_every_toml_reader_uses_the_scan(tmp_path):
    text = WORST["a dotted key of 300 KB"][0]
    path = tmp_path / "x.toml"
    path.write_text(text)
    for call, error in [(lambda: parse_sweep(text, "w.toml"), ScenarioError),
                        (lambda: machine_overrides(str(path)), ScenarioError),
                        (lambda: _spec_table(str(path)), ScenarioError),
                        (lambda: _load_rules(str(path)), ControllerError)]:
        with pytest.raises(error, match=r"x.toml|w.toml") as err:
            call()
        assert "a dotted key of over 16 parts (TOML cap)" in str(err.value)
    with pytest.raises(ScenarioError, match="--set value: a dotted key of over 16 parts"):
        from vrsim.services.sim.overrides import parse_assignment
        parse_assignment("x=" + "{" + ".".join(["a"] * 40) + " = 1}")


def test_values_and_strings_are_no_keys_to_the_scan():
    floats = "x = [" + ", ".join(f"{i}.5" for i in range(5000)) + "]\n"
    dates = "".join(f"d{i} = 1979-05-27T07:32:00.999Z\n" for i in range(300))
    text = 'a = "' + "." * 500 + '"\nb = \'\'\'\n[x]\n' + "." * 100 + "\n'''\n" + floats + dates
    assert len(toml_text.loads_toml(text, "t.toml", ScenarioError)["x"]) == 5000
    text = '[a.b.c]\n"p.q".r = { s.t = [[1.5], [{u.v = 2}]] }\n'
    assert toml_text.loads_toml(text, "t", ScenarioError) == \
        {"a": {"b": {"c": {"p.q": {"r": {"s": {"t": [[1.5], [{"u": {"v": 2}}]]}}}}}}}


def test_the_projects_toml_files_lie_far_inside_the_caps(monkeypatch):
    paths = [p for pattern in ("scenarios/*.toml", "services/sim/scenarios/*.toml", "controller/data/*.toml",
                               "tests/accuracy/scenarios/*.toml", "pyproject.toml")
             for p in glob.glob(os.path.join(ROOT, pattern))]
    assert len(paths) > 20
    monkeypatch.setattr(toml_text, "MAX_TOML_TABLES", toml_text.MAX_TOML_TABLES // 8)
    monkeypatch.setattr(toml_text, "MAX_TOML_DEPTH", toml_text.MAX_TOML_DEPTH // 4)
    for path in paths:
        with open(path, encoding="utf-8") as fh:
            toml_text.loads_toml(fh.read(), path, ScenarioError)


# ---------------------------------------------------------------------------------- catch trays
def _profile(path, rows: int, tail: bytes = b"") -> str:
    offsets = np.linspace(-15.0, 15.0, rows)
    with open(path, "wb") as fh:
        fh.write(b"offset_m,mass\n# trays\n")
        fh.write("".join(f"{x:.6f},1\n" for x in offsets).encode())
        fh.write(tail)
    return str(path)


def test_a_profile_at_the_row_cap_reads_and_one_row_more_is_refused(tmp_path):
    at_cap = _profile(tmp_path / "cap.csv", MAX_PROFILE_ROWS)
    pattern = SpinnerSpec(pattern=at_cap, spread_width_m=30.0).transverse_pattern()
    assert pattern.offset_m.size == MAX_PROFILE_ROWS
    # One row more, 100 KB more rows, then bytes that are no text: the reader stops at the cap and
    # never gets to them.
    over = _profile(tmp_path / "over.csv", MAX_PROFILE_ROWS + 1, tail=b"15,1\n" * 20_000 + b"\xff" * 9)
    with pytest.raises(VehicleError) as err:
        SpinnerSpec(pattern=over, spread_width_m=30.0).transverse_pattern()
    assert str(err.value) == (f"pattern {over}: over {MAX_PROFILE_ROWS:,} rows; a catch-tray profile has "
                              "tens to hundreds of trays")


def test_a_profile_row_longer_than_two_numbers_can_be_is_refused(tmp_path):
    path = tmp_path / "long.csv"
    path.write_text("-10,1\n0," + "1" * 10 * MAX_PROFILE_LINE + "\n10,1\n")
    with pytest.raises(VehicleError, match=rf"long.csv: row 2: over {MAX_PROFILE_LINE} characters"):
        SpinnerSpec(pattern=str(path), spread_width_m=30.0).transverse_pattern()


# ------------------------------------------------------------------------------------------ TimeLog
def test_a_timelog_whose_decoded_arrays_would_not_fit_is_refused_before_allocating(tmp_path):
    """255 DLVs in the header, 5 M records of 7 bytes (time, date, count 0): 35 MB that would decode
    into 7 GB of values and flags (before: MemoryError, exit 1)."""
    dlvs = "".join(f'<DLV A="{i + 1:04X}" C="DET-1"/>' for i in range(255))
    (tmp_path / "TLG00001.xml").write_text(f'<TIM A="" D="4">{dlvs}</TIM>')
    (tmp_path / "TLG00001.bin").write_bytes(bytes(7 * 5_000_000))
    with pytest.raises(MapError) as err:
        read_timelogs(tmp_path / "TLG00001.xml")
    assert str(err.value).startswith(f"{tmp_path / 'TLG00001.xml'}: TLG00001.BIN: decoding 5,000,000 "
                                     "records of 255 DLVs needs about ")
    assert "GB, over the 4.0 GB cap" in str(err.value) or "of memory available" in str(err.value)


# ------------------------------------------------------------------------------- smaller holes
def test_a_sweep_out_under_a_file_is_refused_before_any_run(tmp_path):
    (tmp_path / "file").write_text("")
    out = str(tmp_path / "file" / "out")
    with pytest.raises(ScenarioError, match=f"^{out}: cannot create the folder: .*file is not a folder$"):
        ResultsTable(out)


def test_a_sweep_out_on_a_read_only_file_system_exits_2_naming_the_folder(tmp_path):
    """As root chmod stops no write: a tmpfs remounted read-only, as tests/integration/test_whole_outputs.py
    does (skipped where mounting is refused)."""
    mount = tmp_path / "ro"
    mount.mkdir()
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m,ro", "tmpfs", str(mount)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a read-only tmpfs here: {p.stderr.strip()}")
    try:
        (tmp_path / "q.toml").write_text(f'{FIELD}[map]\nsynthetic = "uniform"\n')
        (tmp_path / "s.toml").write_text('scenarios = ["q.toml"]\nseeds = [1]\n')
        with pytest.raises(ScenarioError, match=f"^cannot write in {mount}: read-only file system"):
            ResultsTable(str(mount / "out"))
        done = subprocess.run([VRSIM, "sweep", str(tmp_path / "s.toml"), "--no-dashboard", "--quiet",
                               "--out", str(mount / "out")], capture_output=True, text=True, timeout=120)
        one_line_exit_2(done, f"cannot write in {mount}: read-only file system")
    finally:
        if subprocess.run(["umount", str(mount)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(mount)], check=True)


KML = ('<?xml version="1.0" encoding="UTF-8"?><kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
       "<Placemark><description>{pad}</description><Polygon><outerBoundaryIs><LinearRing><coordinates>"
       "11.600,52.100 11.601,52.100 11.601,52.101 11.600,52.101 11.600,52.100"
       "</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark></Document></kml>")


def test_a_kmz_is_capped_as_the_zip_it_is(tmp_path):
    path = tmp_path / "field.kmz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:  # 3 MB: over the 1 MB of an unknown kind
        z.writestr("doc.kml", KML.format(pad="x" * 3_000_000))
    assert os.path.getsize(path) > 3_000_000
    assert files.check_file(str(path)) == os.path.getsize(path)
    assert files.cap_for(files.KIND_BY_EXTENSION[".kmz"]) == files.cap_for("zip")
    assert Field.from_file(str(path)).area_ha > 0.5


@pytest.mark.parametrize("key", ["OVERVIEW&#95;FILE", "OVERVIEW&#x5F;FILE", "&#79;VERVIEW_FILE"])
def test_an_aux_xml_naming_a_file_through_character_references_is_refused(tmp_path, key):
    (tmp_path / "rx.tif").write_bytes(b"II*\x00")
    aux = tmp_path / "rx.tif.aux.xml"
    aux.write_text(f'<PAMDataset><Metadata domain="OVERVIEWS"><MDI key="{key}">o.tif</MDI></Metadata>'
                   "</PAMDataset>")
    with pytest.raises(MapError, match="rx.tif: its side file rx.tif.aux.xml names another file"):
        files.check_within(str(tmp_path / "rx.tif"), str(tmp_path), MapError)
    aux.write_text("<PAMDataset><SRS>&#x2F;vsicurl&#x2F;http://x/</SRS></PAMDataset>")
    with pytest.raises(MapError, match="names another file"):
        files.check_within(str(tmp_path / "rx.tif"), str(tmp_path), MapError)
    aux.write_text('<!DOCTYPE d [<!ENTITY f "OVERVIEW_FILE">]><PAMDataset><MDI key="&f;"/></PAMDataset>')
    with pytest.raises(MapError, match="is not plain well-formed XML"):
        files.check_within(str(tmp_path / "rx.tif"), str(tmp_path), MapError)
    aux.write_text('<PAMDataset><Metadata><MDI key="unit">kg/ha</MDI></Metadata></PAMDataset>')
    assert files.check_within(str(tmp_path / "rx.tif"), str(tmp_path), MapError)
