"""The live web page of a run whose map is in lb/ac, with real processes (`vrsim serve all SCENARIO
--web`, the run starting at once) and the page in a real headless Chromium (the approach of
tests/integration/test_web.py): the legend, the rate chart's caption, the live MAE and the report's
rate figures read in lb/ac."""

from __future__ import annotations

import time

import pytest

from tests.integration.test_rate_units import LB_AC, scenario, write_tif
from tests.integration.test_web import (
    CHROMIUM,
    CHROMIUM_ARGS,
    hello,
    need_chromium,
    open_page,
    served_web,
    until,
    wait_done,
)


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    folder = tmp_path_factory.mktemp("web_units")
    scen = scenario(folder, write_tif(folder / "rx.tif", None), map_keys='unit = "lb/ac"', name="q")
    with served_web(str(folder), scen.name) as server:
        yield server


def view_with_map(web, timeout_s: float = 60.0) -> dict:
    """`/api/view` once it carries the run's map: `scenario/start` answers when the run is accepted,
    and the map service loads the map after that."""
    deadline = time.monotonic() + timeout_s
    while (view := web.json("/api/view"))["map"] is None:
        assert time.monotonic() < deadline, f"no map in the view after {timeout_s:g} s: {view}"
        time.sleep(0.2)
    return view


def test_the_view_and_the_runs_hello_carry_the_maps_unit(net):
    scale = view_with_map(net.web)["map"]["scale"]
    assert scale["unit"] == "lb/ac"
    assert (scale["vmin"], scale["vmax"]) == (pytest.approx(100), pytest.approx(150))
    assert scale["vmax_kg_ha"] == pytest.approx(150 * LB_AC)   # the cells are painted on the kg/ha range
    doc = hello(net.web, lambda d: d["run"].get("rate_unit") == "lb/ac", timeout_s=60)
    assert doc["run"]["per_kg_ha"] == pytest.approx(1 / LB_AC)


def test_page_shows_rates_in_lb_ac(net):
    need_chromium()
    from playwright.sync_api import sync_playwright

    ok, status = net.query("vrsim/scenario/status")
    assert ok, status
    wait_done(net, status["run_id"])
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page, errors = open_page(browser, net.web)
            until(page, "window.vrsimView.mapLoaded")
            text = "(id) => document.getElementById(id).textContent"
            assert [page.evaluate(text, i) for i in ("vmin", "vmax", "unit")] == ["100", "150", "lb/ac"]
            until(page, "document.getElementById('rateUnit').textContent === 'lb/ac'", timeout=60_000)
            until(page, "document.getElementById('reportTable').textContent"
                        ".includes('MAE over covered cells, lb/ac')",
                  timeout=60_000)
            rows = page.evaluate("[...document.querySelectorAll('#reportTable tr')]"
                                 ".map((tr) => [...tr.cells].map((c) => c.textContent))")
            report = net.web.json("/api/report")
            assert ["MAE over covered cells, lb/ac", f"{report['in_rate_unit']['mae']:.2f}"] in rows, rows
            assert ["MAE over covered cells, kg/ha", f"{report['mae_kg_ha']:.2f}"] not in rows
            until(page, "document.getElementById('statusTable').textContent"
                        ".includes('per-tick MAE (live), lb/ac')")
            assert errors == []
        finally:
            browser.close()
