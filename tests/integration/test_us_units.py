"""The user's own units end to end, through the real executable and real SUMO runs: a sprayer on a gal/ac
map whose boom, field, nozzle spacing, pressures and speed are given in ft, in, psi and mph prints every
figure, its machine check and its calibration in US units, and its summary.json is, key for key, the
same scenario's written in SI; ``[output] units = "metric"`` shows the same map's figures in metric;
a bad unit string exits 2 in one line naming the key and the value."""

import json
import re

import pytest
import shapefile

from tests.integration.test_rate_units import one_line_exit_2, vrsim
from tests.integration.test_services_support import without_clock

SCENARIO = """name = "boom"
seed = 3
[field]
rectangle = {{ {rectangle}, lat = 48.2, lon = 11.6 }}
headland_passes = 1
[map]
file = "rx.shp"
[implement]
kind = "sprayer"
sections = 6
nozzle = "04"
control = "flow"
flow_meter_pulses_per_l = 600.0
{implement}
[tractor]
{tractor}
[product]
form = "liquid"
density_kg_l = 1.0
[output]
plots = false
html = false
points = "none"
track = "none"
{output}
"""
US = dict(rectangle='width = "600 ft", length = "800 ft"',
          implement='width = "120 ft"\nnozzle_spacing = "20 in"\npressure_range = ["20 psi", "75 psi"]',
          tractor='working_speed = "10 mph"')
PSI_BAR = 0.45359237 * 9.80665 / 0.0254**2 / 1e5
# The same scenario in SI, the numbers a user would type (to 12 digits, as the units are read).
SI = dict(rectangle="width_m = 182.88, length_m = 243.84",
          implement=f"width_m = 36.576\nnozzle_spacing_m = 0.508\npressure_range_bar = "
                    f"[{float(f'{20 * PSI_BAR:.12g}')!r}, {float(f'{75 * PSI_BAR:.12g}')!r}]",
          tractor="working_speed_m_s = 4.4704")
# What differs between two runs of the same scenario: the clock, the file's name and folder.
CLOCK_KEYS = {"wall_time_s", "realtime_factor", "stage_s"}
METRIC_UNITS = re.compile(r"(?<![\w/])(kg|ha|m|m/s|km/h|L|mL|L/min|L/ha|kg/ha|bar)(?![\w/])")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    path = tmp_path_factory.mktemp("us_units")
    write_zones(path / "rx")
    return path


def write_zones(stem, low=10.0, high=15.0):
    """Two zone polygons, west 10 gal/ac and east 15 gal/ac (attribute R_gal_ac), over the field and
    beyond (its south-west corner is 11.6 E, 48.2 N), WGS84 with a .prj."""
    west, south, east, north = 11.5995, 48.1995, 11.6035, 48.2035
    mid = (west + east) / 2
    with shapefile.Writer(str(stem), shapeType=shapefile.POLYGON) as w:
        w.field("R_gal_ac", "N", 8, 2)
        for (a, b), rate in (((west, mid), low), ((mid, east), high)):
            w.poly([[(a, south), (a, north), (b, north), (b, south), (a, south)]])
            w.record(rate)
    with open(f"{stem}.prj", "w") as fh:
        fh.write('GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],'
                 'PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]]')


def scenario(folder, name, keys, output=""):
    path = folder / f"{name}.toml"
    path.write_text(SCENARIO.format(output=output, **keys))
    return path


def comparable(summary: dict) -> dict:
    """A summary without the clock, the scenario file's path and folder."""
    out = without_clock(summary, CLOCK_KEYS)
    out["scenario_config"] = {k: v for k, v in out["scenario_config"].items()
                              if k not in ("source", "base_dir")}
    return out


def test_a_gal_ac_sprayer_in_ft_and_mph_prints_us_units_and_its_json_is_the_si_scenarios(folder):
    us_run = vrsim("run", scenario(folder, "us", US), "--quiet", "--out", folder / "us_out")
    si_run = vrsim("run", scenario(folder, "si", SI), "--quiet", "--out", folder / "si_out")
    assert us_run.returncode == 0 and si_run.returncode == 0, (us_run.stderr, si_run.stderr)
    # Both show US units (the map is in gal/ac) and print the same.
    assert _same_but_clock(us_run.stdout, si_run.stdout), (us_run.stdout, si_run.stdout)
    check, figures = us_run.stdout.split("vrsim run: boom")
    assert "10-15 gal/ac at 9.50-10.50 mph" in check and "gpm of a boom" in check, check
    lines = [line for line in figures.splitlines()[1:] if not line.strip().startswith("outputs in")]
    assert len(lines) > 30
    for line in check.splitlines() + lines:
        assert not METRIC_UNITS.search(line), line
    shown = {line[:40].strip(): line[40:].split()[-1] for line in lines if not line.rstrip().endswith(" ")}
    # A liquid's product by its volume, as its rates: gal.
    assert shown["Field area"] == "ac" and shown["Applied product"] == "gal" and shown["Bias"] == "gal/ac"
    assert shown["Highest speed for the map"] == "mph" and shown["Section widths"] == "ft"
    assert "20, 20, 20, 20, 20, 20 ft" in figures
    us_json = json.loads((folder / "us_out" / "summary.json").read_text())
    si_json = json.loads((folder / "si_out" / "summary.json").read_text())
    assert us_json["scenario_config"]["implement"]["width_m"] == 36.576
    assert comparable(us_json) == comparable(si_json)
    # The keys stay SI; the display block gives each figure in the units shown.
    assert us_json["units"] == "us" and us_json["section_widths_m"] == [6.096] * 6
    assert us_json["display"]["section_widths_m"]["unit"] == "ft"
    assert us_json["display"]["section_widths_m"]["value"] == pytest.approx([20.0] * 6, rel=1e-12)
    litres = us_json["applied_kg"] / us_json["scenario_config"]["product"]["density_kg_l"]
    assert us_json["in_product_unit"]["applied_kg"] == pytest.approx(litres, rel=1e-12)
    assert us_json["display"]["applied_kg"] == {"value": pytest.approx(litres / 3.785411784, rel=1e-12),
                                                "unit": "gal"}
    assert us_json["display"]["mae_kg_ha"] == {"value": us_json["in_rate_unit"]["mae"], "unit": "gal/ac"}


def _same_but_clock(a: str, b: str) -> bool:
    """The two printouts line for line, the clock's lines (wall time, real-time factor) and the outputs'
    folder aside."""
    skip = ("Wall time", "Real-time factor", "outputs in")
    return [x for x in a.splitlines() if not x.strip().startswith(skip)] == \
        [x for x in b.splitlines() if not x.strip().startswith(skip)]


def test_output_units_metric_on_a_gal_ac_map_shows_metric(folder):
    path = scenario(folder, "metric", US, output='units = "metric"')
    check = vrsim("run", path, "--check")
    assert check.returncode == 0, check.stderr
    assert "94-140 L/ha at 4.25-4.69 m/s" in check.stdout and "L/min of a boom" in check.stdout, check.stdout
    assert "mph" not in check.stdout and "gal" not in check.stdout
    doc = json.loads(vrsim("run", path, "--check", "--json").stdout)
    assert doc["units"] == "metric" and doc["display"]["speed_max_m_s"] == {"value": doc["speed_max_m_s"],
                                                                              "unit": "m/s"}
    us_doc = json.loads(vrsim("run", scenario(folder, "us_check", US), "--check", "--json").stdout)
    assert us_doc["units"] == "us" and us_doc["display"]["speed_max_m_s"]["unit"] == "mph"
    assert us_doc["display"]["rate_max_kg_ha"] == {"value": pytest.approx(15.0, rel=1e-9), "unit": "gal/ac"}
    assert us_doc["speed_max_m_s"] == doc["speed_max_m_s"]


def test_calibration_in_us_units_and_in_metric(folder):
    us = vrsim("calibrate", scenario(folder, "us_cal", US))
    metric = vrsim("calibrate", scenario(folder, "metric_cal", US, output='units = "metric"'))
    assert us.returncode == 0 and metric.returncode == 0, (us.stderr, metric.stderr)
    assert "at 43.5 psi" in us.stdout and " floz." in us.stdout and re.search(r"Jugs [\d.]+ gal ", us.stdout)
    assert "at 3 bar" in metric.stdout and "+-10 mL." in metric.stdout and re.search(r"Jugs [\d.]+ L ",
                                                                                    metric.stdout)


@pytest.mark.parametrize("override, says", [
    ('implement.width="120 kg"', "[implement] width '120 kg' is not a length"),
    ('tractor.working_speed="10 knotz"', "[tractor] working_speed '10 knotz' has a unit pint does not read"),
    ('implement.pressure_range=["20 psi", "75 ft"]',
     "[implement] pressure_range ['20 psi', '75 ft'] is not a pressure"),
])
def test_a_bad_unit_string_exits_2_in_one_line_naming_key_and_value(folder, override, says):
    path = scenario(folder, "bad", {**US, "implement": "", "tractor": ""})
    one_line_exit_2(vrsim("run", path, "--check", "--set", override), "bad.toml", says)
