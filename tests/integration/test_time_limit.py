"""The time limit of a run: derived from the path unless the scenario sets one, so a large field runs
without a [timing] table (the old fixed default stopped at 36,000 s of simulated time)."""

import pytest

from vrsim.services.sim import run, scenario

FIELD_500_HA = """
name = "field_500ha"
seed = 7
[field]
rectangle = { width_m = 2000.0, length_m = 2500.0, lat = 52.0, lon = 10.0 }
[map]
synthetic = "zones"
cell_size_m = 4.0
params = { n_zones = 12 }
[implement]
width_m = 24.0
sections = 8
[tractor]
working_speed_m_s = 3.0
[output]
plots = false
html = false
"""


@pytest.mark.slow
def test_500_ha_with_a_24_m_boom_at_3_m_s_runs_without_a_timing_table(tmp_path):
    path = tmp_path / "field_500ha.toml"
    path.write_text(FIELD_500_HA)
    sc = scenario.load(str(path))
    assert sc.timing.max_sim_time_s is None  # no [timing] table: the driver derives the limit
    result = run(sc)
    s = result.summary
    assert s["field_area_ha"] == pytest.approx(500.0)
    assert s["sim_time_s"] > 36000.0  # beyond the old fixed limit: ~20 h of driving
    assert s["coverage_pct"] > 95.0 and abs(s["mass_balance_pct"]) < 10.0
