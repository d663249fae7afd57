"""The live page follows the run it runs, in a real headless Chromium: a second scenario repaints the
prescription, field and path; a mid-run report is marked partial; the real-time factor asked and kept
is shown (`vrsim serve all --web`, the page driven by Playwright as in test_web.py)."""

from __future__ import annotations

import io
import json
import os
import uuid
import zipfile

import pytest

from tests.conftest import ROOT
from tests.integration.test_web import (
    CHROMIUM,
    CHROMIUM_ARGS,
    SCENARIO,
    need_chromium,
    open_page,
    served_web,
    until,
)

OTHER = """# Another field and prescription than quick_rectangle's: the page must repaint both.
name = "other_rectangle"
seed = 11

[field]
rectangle = { width_m = 120.0, length_m = 150.0, lat = 48.2, lon = 11.6 }
headland_passes = 1

[map]
synthetic = "random_field"
cell_size_m = 2.0
params = { mean_kg_ha = 90.0, std_kg_ha = 25.0, correlation_length_m = 20.0 }

[implement]
width_m = 12.0
delivery_delay_s = 0.8
"""


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    with served_web(str(tmp_path_factory.mktemp("web-runs"))) as server:
        yield server


def start_from_page(page, path: str, clock: str, speed: str) -> None:
    page.set_input_files("#scenario", path)
    page.select_option("#clock", clock)
    page.fill("#speed", speed)
    page.click("#start")


def shown(page) -> dict:
    return page.evaluate("(() => { const s = window.vrsimView; return {run: s.runId, "
                         "scenario: s.run.scenario, field: s.run.field || null, shown: s.mapShown, "
                         "version: s.mapVersion, "
                         "realtime: s.realtime, partial: s.reportPartial, "
                         "reportState: document.getElementById('reportState').textContent, "
                         "status: document.getElementById('statusTable').innerText}; })()")


def test_a_second_run_repaints_the_prescription_field_and_path_and_reports_say_partial(net, tmp_path):
    need_chromium()
    from playwright.sync_api import sync_playwright

    other = tmp_path / "other_rectangle.toml"
    other.write_text(OTHER)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page, errors = open_page(browser, net.web)
            until(page, "window.vrsimView.role === 'operator' && window.vrsimView.mapLoaded")
            # The first run at 40 x real time: asked and kept shown; its report mid-run says partial.
            start_from_page(page, SCENARIO, "realtime", "40")
            until(page, "window.vrsimView.status && window.vrsimView.status.state === 'running' && "
                        "window.vrsimView.realtime && window.vrsimView.realtime.kept !== null && "
                        "window.vrsimView.run.field && "
                        "window.vrsimView.mapShown === window.vrsimView.mapVersion",
                  timeout=60_000)
            first = shown(page)
            assert first["scenario"] == "quick_rectangle"
            assert first["realtime"]["asked"] == 40 and first["realtime"]["kept"] > 0
            assert "×40" in first["status"]
            until(page, "window.vrsimView.reportPartial === true", timeout=60_000)
            mid = shown(page)
            assert mid["reportState"].startswith("partial: the run so far")
            assert "not final" in mid["reportState"]
            page.click("#stop")
            until(page, "window.vrsimView.status.state === 'stopped' && "
                        "document.getElementById('reportState').textContent.includes('stopped')",
                  timeout=60_000)
            assert shown(page)["partial"] is True
            first_png = net.web.get("/api/map.png")[1]
            # The second run, another field and map, lockstep: the page shows its prescription, field
            # and path without a reload, and its final report as final.
            start_from_page(page, str(other), "lockstep", "1")
            until(page, f"window.vrsimView.runId !== '{first['run']}' && window.vrsimView.run.scenario === "
                        "'other_rectangle' && window.vrsimView.run.field && window.vrsimView.mapLoaded && "
                        f"window.vrsimView.mapShown === window.vrsimView.mapVersion && "
                        f"window.vrsimView.mapVersion !== {first['version']}", timeout=60_000)
            second = shown(page)
            view = net.web.json("/api/view")
            assert second["shown"] == view["map"]["version"] != first["version"]
            assert net.web.get("/api/map.png")[1] != first_png
            assert second["field"] != first["field"]
            xs = [x for x, _ in second["field"]["boundary"][0]]
            assert 110 < max(xs) - min(xs) < 130 or 140 < max(xs) - min(xs) < 160  # the 120 x 150 m field
            until(page, "window.vrsimView.status.state === 'finished' && "
                        "window.vrsimView.reportPartial === false",
                  timeout=120_000)
            assert shown(page)["reportState"] == "final: the whole run"
            assert errors == []
        finally:
            browser.close()


# ------------------------------------------------------------------------------------- uploads
DATA = os.path.join(ROOT, "scenarios", "data")
FLAT = open(os.path.join(ROOT, "scenarios", "geojson_field_geotiff_map.toml")).read().replace(
    "data/field.geojson", "field.geojson").replace("data/prescription.tif", "prescription.tif")


def multipart(files: list[tuple[str, bytes]]) -> tuple[bytes, dict]:
    """A multipart/form-data body of ``files`` (name, bytes), each as a part named ``files``."""
    boundary = "vrsim-test-" + uuid.uuid4().hex
    body = b"".join(f"--{boundary}\r\nContent-Disposition: form-data; name=\"files\"; filename=\"{name}\"\r\n"
                    f"Content-Type: application/octet-stream\r\n\r\n".encode() + data + b"\r\n"
                    for name, data in files) + f"--{boundary}--\r\n".encode()
    return body, {"Content-Type": f"multipart/form-data; boundary={boundary}"}


def upload(net, files: list[tuple[str, bytes]], query: str = "") -> tuple[int, dict]:
    body, headers = multipart(files)
    code, reply, _ = net.web.request("POST", f"/api/start{query}", body, headers)
    return code, json.loads(reply)


def data(name: str) -> bytes:
    with open(os.path.join(DATA, name), "rb") as fh:
        return fh.read()


def run_then_stop(net, reply: dict, scenario: str) -> None:
    status = net.wait_status(lambda s: s["run_id"] == reply["run_id"]
                             and s["state"] in ("running", "finished"))
    assert status["scenario"] == scenario
    net.web.request("POST", "/api/stop")
    net.wait_status(lambda s: s["run_id"] == reply["run_id"] and s["state"] in ("stopped", "finished"))


def test_a_scenario_uploaded_with_its_files_runs_and_bad_uploads_are_refused_in_one_line(net):
    uploads = os.path.join(net.folder, "runs", "uploads")  # under the data root: the folder serve runs in
    before = set(os.listdir(uploads)) if os.path.isdir(uploads) else set()  # the page's, earlier
    # The scenario alone, naming files it did not bring: what to upload, before the bus is asked.
    code, reply = upload(net, [("flat.toml", FLAT.encode())])
    assert code == 400 and reply["error"] == (
        "upload: flat.toml names [field] file field.geojson, which is not in the upload: choose it "
        "together with the scenario (a shapefile with its .shx, .dbf and .prj), or upload a .zip of the "
        "scenario's folder")
    # With its files: kept under the data root, started from there.
    files = [("flat.toml", FLAT.encode()), ("field.geojson", data("field.geojson")),
             ("prescription.tif", data("prescription.tif"))]
    code, reply = upload(net, files, "?clock=lockstep")
    assert code == 200 and reply["accepted"] is True, reply
    run_then_stop(net, reply, "geojson_field_geotiff_map")
    kept = sorted(set(os.listdir(uploads)) - before)
    assert len(kept) == 1 and sorted(os.listdir(os.path.join(uploads, kept[0]))) == [
        "field.geojson", "flat.toml", "prescription.tif"]
    # A zip of the scenario's folder, its layout kept (data/...).
    packed = io.BytesIO()
    with zipfile.ZipFile(packed, "w") as archive:
        archive.write(os.path.join(ROOT, "scenarios", "geojson_field_geotiff_map.toml"), "rx/scenario.toml")
        for name in ("field.geojson", "prescription.tif"):
            archive.write(os.path.join(DATA, name), f"rx/data/{name}")
    code, reply = upload(net, [("rx.zip", packed.getvalue())])
    assert code == 200 and reply["accepted"] is True, reply
    run_then_stop(net, reply, "geojson_field_geotiff_map")
    # Refused, each in one line, nothing kept: a path in a name, a zip member leaving its folder, a file
    # over its format's cap, an upload over the cap.
    evil = io.BytesIO()
    with zipfile.ZipFile(evil, "w") as archive:
        archive.writestr("scenario.toml", FLAT)
        archive.writestr("../field.geojson", data("field.geojson"))
    refused = [(upload(net, [("../flat.toml", FLAT.encode())]), 400, "only letters, digits"),
               (upload(net, [("evil.zip", evil.getvalue())]), 400, "member '../field.geojson'"),
               (upload(net, [("big.toml", b"#" * ((1 << 20) + 1))]), 413, "big.toml: over the 1 MB"),
               (upload(net, [("x.exe", b"MZ")]), 400, "x.exe: not a file vrsim reads")]
    for (code, reply), want_code, words in refused:
        assert code == want_code and words in reply["error"] and "\n" not in reply["error"], (code, reply)
    # An upload that says it is over the cap is answered before it is sent.
    _, headers = multipart([])
    code, reply, _ = net.web.request("POST", "/api/start", b"", {**headers, "Content-Length": str(257 << 20)})
    assert code == 413 and json.loads(reply)["error"] == "/api/start: the upload is larger than 256 MB"
    assert len(set(os.listdir(uploads)) - before) == 2  # the two good ones only
    assert net.web.json("/api/status")["alive"]  # the service goes on serving
