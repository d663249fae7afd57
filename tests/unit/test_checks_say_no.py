"""Issue #37, "checks that say no", in process: the machine check reads a vector map's zone rates, not
the means its rasterizing gives the cells on a zone edge; its advice never names the setting in place
and stays within field speeds; a loop's margins below 6 dB or 45 deg are said (`vrsim tune`). The
executable's exit codes: tests/integration/test_checks_say_no.py."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pyproj import CRS

from vrsim.controller import ControllerConfig, PlantParams
from vrsim.controller.analysis import analyze_loop
from vrsim.maps import read_map
from vrsim.maps.units import convert_rate
from vrsim.services.sim.analyze import margin_warning
from vrsim.services.sim.limits import RATES_FROM_CELLS, RATES_FROM_ZONES, _map_rates, machine_check
from vrsim.vehicle import Implement
from vrsim.vehicle.driver import MAX_WORKING_SPEED_M_S
from vrsim.vehicle.sprayer import SprayerSpec

LB_AC = float(convert_rate(1.0, "lb/ac", "kg/ha"))
# Two zones, 0 and 10 lb/ac, split by a diagonal: rasterized at 2 m, the cells it crosses hold means.
W, E, S, N = 11.5995, 11.6035, 52.0995, 52.1020
ZONES = {"type": "FeatureCollection", "features": [
    {"type": "Feature", "properties": {"Rate_lb_ac": rate},
     "geometry": {"type": "Polygon", "coordinates": [ring]}}
    for rate, ring in ((0.0, [[W, S], [E, S], [W, N], [W, S]]), (10.0, [[E, S], [E, N], [W, N], [E, S]]))]}


def zone_map(folder):
    """ZONES as a GeoJSON file in `folder`; its path."""
    path = folder / "zones_0_10.geojson"
    path.write_text(json.dumps(ZONES))
    return path


def test_a_rasterized_zone_map_keeps_its_zones_rates_beside_its_edge_cells(tmp_path):
    grid = read_map(str(zone_map(tmp_path)), cell_size_m=2.0)
    assert grid.zone_rates_kg_ha == pytest.approx([0.0, 10.0 * LB_AC], rel=1e-12)   # read in lb/ac
    rates = grid.rates_kg_ha[np.isfinite(grid.rates_kg_ha)]
    edge = rates[(rates > 0) & ~np.isclose(rates, 10.0 * LB_AC, rtol=1e-9)]
    assert edge.size > 50 and edge.min() < 0.2 * LB_AC   # means of the two zones, down to 1/64 of 10
    assert np.allclose(grid.in_map_unit(grid.zone_rates_kg_ha), [0.0, 10.0])
    # Another CRS (interpolated near the edges) and a unit of its own keep them too.
    moved = grid.reproject(CRS.from_epsg(32633))
    assert moved.zone_rates_kg_ha == pytest.approx(grid.zone_rates_kg_ha)
    assert grid.as_map_unit().zone_rates_kg_ha == pytest.approx([0.0, 10.0])
    raster = read_map(str(zone_map(tmp_path)), cell_size_m=2.0)
    raster.zone_rates_kg_ha = None
    assert _map_rates(raster.rates_kg_ha)[1] == RATES_FROM_CELLS


def test_the_check_reads_the_zone_rates_not_the_edge_cells_means(tmp_path):
    grid = read_map(str(zone_map(tmp_path)), cell_size_m=2.0)
    rates, rule = _map_rates(grid.rates_kg_ha, grid.zone_rates_kg_ha)
    assert rule == RATES_FROM_ZONES and rates == pytest.approx([0.0, 10.0 * LB_AC])
    cells, rule = _map_rates(grid.rates_kg_ha)
    assert rule == RATES_FROM_CELLS and cells[cells > 0].min() < 0.2 * LB_AC
    # 0.25 kg/rev: 10 lb/ac on a 12 m boom at 2.38-2.62 m/s needs 7.7-8.5 rpm of a 5-150 rpm shaft.
    imp = Implement(kg_per_rev=0.25)
    check = machine_check(grid.rates_kg_ha, (2.38, 2.62), imp, zone_rates_kg_ha=grid.zone_rates_kg_ha)
    assert check.can_apply and check.rates_from == RATES_FROM_ZONES
    assert check.in_rate_unit(grid)["rate_min"] == pytest.approx(10.0)
    # As the run prints it: a map in lb/ac shows US units (`[output] units`), "metric" converts its rates.
    assert "10-10 lb/ac at 5.32-5.86 mph" in check.text(grid)
    assert "11-11 kg/ha at 2.38-2.62 m/s" in check.text(grid, "metric")
    assert "Rates: the zone rates of the vector map inside the field" in check.text(grid)
    assert 1.0 < check.min_speed_m_s < 2.0
    # Read as cells, an edge cell's 0.156 lb/ac is the lowest rate: 64x the rates, for a 30x shaft.
    edges = machine_check(grid.rates_kg_ha, (2.38, 2.62), imp)
    assert not edges.can_apply and edges.min_speed_m_s > MAX_WORKING_SPEED_M_S
    assert edges.speed_window_m_s is None and "Rates: the map's cell values inside the field." in edges.text()
    assert "Working speeds at which it can: none (the map's rates span 64.0x" in edges.text()


def test_a_field_on_edge_cells_only_falls_back_to_their_values():
    rates, rule = _map_rates(np.array([2.5, 5.0, np.nan]), np.array([0.0, 10.0]))
    assert rule == RATES_FROM_CELLS and rates.tolist() == [2.5, 5.0]
    rates, rule = _map_rates(np.array([0.0, 2.5, 10.0 * (1 + 1e-12)]), np.array([10.0, 0.0, 10.0]))
    assert rule == RATES_FROM_ZONES and rates.tolist() == [0.0, 10.0]


def test_the_speed_advice_stays_within_field_speeds():
    # 10 kg/ha on a 12 m boom: the shaft's 5 rpm needs 3.47 m/s, its 150 rpm 104 m/s: advised up to 15.
    check = machine_check(np.array([10.0]), (1.9, 2.1), Implement())
    assert not check.can_apply and check.max_speed_m_s > 50
    assert check.speed_window_m_s == pytest.approx((check.min_speed_m_s, MAX_WORKING_SPEED_M_S))
    text = check.text()
    assert f"keep the working speeds within {check.min_speed_m_s:.2f}-15.00 m/s, or" in text
    assert "(highest 54.0 km/h; field speeds end at 15 m/s)" in text
    # 1 kg/ha needs 34.7 m/s for the shaft's 5 rpm: no field speed, and none advised.
    slow = machine_check(np.array([1.0, 2.0]), (1.9, 2.1), Implement())
    assert slow.speed_window_m_s is None and slow.min_speed_m_s == pytest.approx(34.72, abs=0.01)
    text = slow.text()
    assert "Working speeds at which it can: none (it needs 34.72 m/s or more, beyond field speeds" in text
    assert "At every field speed the lowest rates are over-applied." in text
    assert "No field speed applies it all" in text and "set [implement] kg_per_rev to" in text
    assert "keep the working speeds" not in text


def _sprayer(**keys) -> Implement:
    spec = SprayerSpec(**{"nozzle_spacing_m": 0.5, "pressure_range_bar": (1.5, 5.0), **keys})
    return Implement(width_m=12.0, sections=6, kind="sprayer", machine=spec)


def test_the_nozzle_advice_never_names_the_nozzle_on_the_boom():
    """The issue's case: '05' nozzles at 4 m/s with a 3 m/s headland, 155-175 L/ha. At 4 m/s the '05'
    itself is the best-centred size, so the old advice was to set it; no size covers 3-4.2 m/s."""
    imp = _sprayer(nozzle="05")
    check = machine_check(np.array([155.0, 175.0]), (3.0, 4.2), imp, 1.0, 4.0)
    assert not check.can_apply and imp.machine.suggest_nozzle(155.0, 175.0, 4.0) == "05"
    assert check.nozzle_suggested is None and check.nozzles_advised == ()
    text = check.text()
    assert "nozzle = '05'" not in text and "no other nozzle size applies it at 3.00-4.20 m/s." in text
    assert "keep the working speeds within 3.04-4.92 m/s, or" in text
    # 190-210 L/ha at 3.8-4.2 m/s: the '05' tops out at 4.10 m/s; the '06' covers every working speed.
    check = machine_check(np.array([190.0, 210.0]), (3.8, 4.2), imp, 1.0, 4.0)
    assert check.nozzles_advised == ("06",)
    assert "set [implement] nozzle = '06' (now '05') to apply it at 3.80-4.20 m/s." in check.text()


def test_nozzles_for_gives_the_nearest_smaller_and_larger_size_that_cover_every_speed():
    spec = SprayerSpec(nozzle="04", control="pwm", duty_range_pct=(10.0, 100.0))
    # 100 L/ha at 2.5 m/s every 0.5 m: 0.75 L/min a nozzle; PWM's 10-100 % duty spans ten times.
    sizes = spec.nozzles_for(100.0, 100.0, (2.4, 2.6))
    assert "04" not in sizes and sizes == ["05", "03"]   # the 05 is nearer in flow (1.25x against 1.33x)
    for size in sizes:
        lo, hi = spec.speed_range_m_s(100.0, 100.0, size)
        assert lo <= 2.4 and 2.6 <= hi
    assert SprayerSpec(nozzle="02").nozzles_for(20.0, 800.0, (2.4, 2.6)) == []


def test_margins_below_6_db_or_45_deg_are_said():
    plant = PlantParams()
    safe = analyze_loop(plant, ControllerConfig(kind="PI", gains="manual", kp=0.05, ki=0.1), 0.05)
    assert safe.gain_margin_db > 6 and safe.phase_margin_deg > 45 and margin_warning(safe) is None
    edgy = analyze_loop(plant, ControllerConfig(kind="PI", gains="manual", kp=0.45, ki=7.5), 0.05)
    warning = margin_warning(edgy)
    assert edgy.closed_loop_stable and edgy.gain_margin_db < 6 and "is below 6 dB" in warning
    assert f"{edgy.gain_margin_db:.1f} dB" in warning
    unstable = analyze_loop(plant, ControllerConfig(kind="PI", gains="manual", kp=2.0, ki=10.0), 0.05)
    assert margin_warning(unstable).startswith("closed loop is UNSTABLE")
    assert margin_warning(None) is None
