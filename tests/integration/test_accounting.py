"""One accounting path (real SUMO on a small field): a figure added as one row of `METRICS` and its
formula reaches the run's summary, its JSON, the text and HTML reports and the controller variants,
with no other change."""

import json

import numpy as np
import pytest

from vrsim.controller import ControllerConfig
from vrsim.services.outputs.report import figures_table
from vrsim.services.outputs.summary import summary_json, summary_rows, text_summary
from vrsim.services.sim import metrics
from vrsim.services.sim.run import control_and_account, drive
from vrsim.services.sim.scenario import parse
from vrsim.services.sim.variants import run_variants

FIELD = """
name = "accounting"
seed = 7
[field]
rectangle = { width_m = 48.0, length_m = 100.0, lat = 52.0, lon = 10.0 }
headland_passes = 1
[map]
synthetic = "zones"
cell_size_m = 2.0
params = { n_zones = 4 }
[implement]
width_m = 12.0
sections = 3
"""


def _peak_applied_kg_ha(a) -> float:
    """The formula of the added figure: the highest applied rate over the field's covered cells."""
    d, s = a.deposit, a.setting
    covered = s.in_field & (d.coverage_fraction >= metrics.COVERED_FRACTION)
    return float(d.applied_kg_ha[covered].max())


PEAK = metrics.Metric("peak_applied_kg_ha", "kg/ha", "Peak applied rate",
                      "highest applied rate over the covered cells in the field", of=_peak_applied_kg_ha)


@pytest.fixture(scope="module")
def small_drive():
    return drive(parse(FIELD, "accounting.toml", "."))


def test_a_figure_added_to_the_table_is_in_the_summary_its_json_the_reports_and_the_variants(
        small_drive, monkeypatch):
    monkeypatch.setattr(metrics, "METRICS", (*metrics.METRICS, PEAK))
    result = control_and_account(small_drive)
    peak = result.summary["peak_applied_kg_ha"]
    covered = result.in_field & (result.as_applied.coverage_fraction >= metrics.COVERED_FRACTION)
    assert peak == float(result.as_applied.applied_kg_ha[covered].max()) > 0
    assert list(result.summary)[-6:] == ["peak_applied_kg_ha", "rate_unit", "in_rate_unit", "seed",
                                         "stage_s", "units"]   # in table order
    assert result.summary["in_rate_unit"]["peak_applied"] == peak  # a kg/ha figure, in the map's unit too
    assert json.loads(summary_json(result.summary))["peak_applied_kg_ha"] == peak
    line = next(line for line in text_summary(result.summary).splitlines() if "Peak applied rate" in line)
    assert f"{peak:,.2f}" in line and line.rstrip().endswith("kg/ha")
    assert ("Peak applied rate", "peak_applied_kg_ha", "kg/ha") in summary_rows()
    assert "Peak applied rate" in figures_table(summary_rows(), result.summary)
    fast, = run_variants(small_drive, [small_drive.world.scenario.controller])
    assert fast["peak_applied_kg_ha"] == pytest.approx(peak, rel=1e-9)


def test_the_timer_gives_the_summary_its_wall_time_and_stages(small_drive):
    result = control_and_account(small_drive)
    s, timing = result.summary, result.accounts.timing
    assert list(s["stage_s"]) == ["build_s", "sumo_s", "sensors_s", "control_s", "metrics_s"]
    assert s["wall_time_s"] == timing.wall_time_s >= sum(s["stage_s"].values()) * (1 - 1e-9)
    assert s["realtime_factor"] == s["sim_time_s"] / s["wall_time_s"]
    assert s["sim_time_s"] == s["ticks"] * small_drive.world.scenario.timing.control_period_s
    # the documented API's names read the same accounts
    assert result.stage_s == s["stage_s"] and result.map_metrics.mae_kg_ha == s["mae_kg_ha"]
    assert result.transition_metrics.transitions == s["transitions"]
    assert result.overlap_metrics.overlap_kg == s["overlap_kg"]
    assert result.limit_metrics.limited_time_pct == s["limited_time_pct"]
    variant, = run_variants(small_drive, [ControllerConfig(kind="PID")])
    assert variant["wall_time_s"] == pytest.approx(sum(variant["stage_s"].values()), rel=1e-12)
    assert np.isfinite(variant["realtime_factor"])
