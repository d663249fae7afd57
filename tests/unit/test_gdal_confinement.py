"""Files opened only as what they claim to be (issue 28): a GDAL VRT under a .tif name, side files
that lead GDAL elsewhere (external overviews, an .aux.xml), a shapefile whose .prj or .dbf is a
symlink out of the data root, a /vsi path: refused with one line naming the file, before the file
outside is opened or a single HTTP request is sent. Through the readers, the map service's load
handler (what answers ``<prefix>/map/load`` on the bus) and ``vrsim map info``."""

from __future__ import annotations

import http.server
import os
import subprocess
import sys
import threading

import numpy as np
import pyproj
import pytest
import rasterio
import shapefile
from affine import Affine

from tests.conftest import VRSIM
from vrsim.common import VrsimError
from vrsim.maps import read_map
from vrsim.maps.pointlog import read_point_log
from vrsim.services.bus import messages
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.map import _MapService
from vrsim.services.bus.serving import Params
from vrsim.vehicle.field import Field

X0, Y0 = 500_000.0, 5_300_050.0  # EPSG:32632, near 47.8 N, 9 E
FIELD = '[field]\nrectangle = { width_m = 40.0, length_m = 40.0, lat = 47.8535, lon = 9.0002 }\n'
SECRET = 1234.0  # the value only the raster outside the root holds


@pytest.fixture()
def web():
    """A local HTTP server that counts every request it gets (and answers 404)."""
    hits = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - the http.server API
            hits.append(self.path)
            self.send_response(404)
            self.end_headers()

        do_HEAD = do_GET

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}", hits
    server.shutdown()
    server.server_close()


@pytest.fixture()
def place(tmp_path):
    """(root, outside): a data root and a folder beside it holding a GeoTIFF of `SECRET`."""
    root, outside = tmp_path / "root", tmp_path / "outside"
    root.mkdir()
    outside.mkdir()
    _geotiff(outside / "secret.tif", SECRET)
    return root, outside


def _geotiff(path, value: float) -> None:
    with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(10, 0, X0, 0, -10, Y0)) as dst:
        dst.write(np.full((4, 4), value, np.float32), 1)
        dst.units = ("kg/ha",)


def _vrt(source: str) -> str:
    return ('<VRTDataset rasterXSize="4" rasterYSize="4"><SRS>EPSG:32632</SRS>'
            f'<GeoTransform>{X0}, 10, 0, {Y0}, 0, -10</GeoTransform>'
            '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
            f'<SourceFilename relativeToVRT="0">{source}</SourceFilename><SourceBand>1</SourceBand>'
            '</SimpleSource></VRTRasterBand></VRTDataset>')


class Untouched:
    """Tells whether a file was read: its access time is set well before its modification time, which
    the kernel (relatime) then moves forward on the next read."""

    def __init__(self, path):
        self.path = path
        st = os.stat(path)
        os.utime(path, ns=(st.st_mtime_ns - 3600 * 10**9, st.st_mtime_ns))
        self.atime_ns = os.stat(path).st_atime_ns

    def untouched(self) -> bool:
        return os.stat(self.path).st_atime_ns == self.atime_ns


@pytest.fixture()
def watch(tmp_path):
    """`Untouched` for a file, once it is shown that reads move the access time on this file system."""
    probe = tmp_path / "probe.bin"
    probe.write_bytes(b"x" * 100)
    seen = Untouched(probe)
    probe.read_bytes()
    if seen.untouched():
        pytest.skip("this file system does not record reads (noatime)")
    return Untouched


def _load(root, text: str):
    """The map service's ``load`` handler (an exception becomes the bus's error reply) for a scenario
    received over the bus whose files resolve under ``root``."""
    svc = _MapService(None, False, DataRoot(str(root)))
    start = messages.RunStart(run_id="r1", scenario_text=text, source="bus.toml", base_dir=str(root),
                              clock="lockstep", speed=1.0, ticks_per_message=1)
    return svc.load(Params("vrsim/map/load", []), start.to_json())


def _refused(call, *names: str) -> str:
    with pytest.raises(VrsimError) as err:
        call()
    message = str(err.value)
    assert "\n" not in message and all(name in message for name in names), message
    assert str(int(SECRET)) not in message
    return message


# ------------------------------------------------------------------------------------------ VRT
def test_a_vrt_named_tif_reading_a_raster_outside_the_root_is_refused_unopened(place, watch):
    root, outside = place
    (root / "evil.tif").write_text(_vrt(str(outside / "secret.tif")))
    secret = watch(outside / "secret.tif")
    message = _refused(lambda: _load(root, FIELD + '[map]\nfile = "evil.tif"\n'), "evil.tif")
    assert "not a GeoTIFF" in message
    _refused(lambda: read_map(root / "evil.tif"), "evil.tif", "not a GeoTIFF")  # locally as well
    assert secret.untouched()


def test_a_vrt_with_a_vsicurl_source_sends_no_request(place, web):
    root, _ = place
    url, hits = web
    (root / "net.tif").write_text(_vrt(f"/vsicurl/{url}/x.tif"))
    _refused(lambda: _load(root, FIELD + '[map]\nfile = "net.tif"\n'), "net.tif", "not a GeoTIFF")
    _refused(lambda: read_map(root / "net.tif"), "net.tif")
    assert hits == []


def test_the_cli_refuses_a_vrt_named_tif_in_one_line_with_exit_2(place):
    root, outside = place
    (root / "evil.tif").write_text(_vrt(str(outside / "secret.tif")))
    done = subprocess.run([VRSIM, "map", "info", str(root / "evil.tif")], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "evil.tif" in lines[0] and "not a GeoTIFF" in lines[0], done.stderr
    assert "Traceback" not in done.stderr and str(int(SECRET)) not in done.stdout + done.stderr


# ---------------------------------------------------------------------------------- side files
def test_side_files_leading_out_are_refused_in_the_data_root_and_ignored_locally(place, web, watch):
    root, outside = place
    url, hits = web
    _geotiff(root / "ovr.tif", 7.0)
    (root / "ovr.tif.ovr").write_text(_vrt(str(outside / "secret.tif")))  # external overviews, a VRT
    _geotiff(root / "aux.tif", 7.0)
    (root / "aux.tif.aux.xml").write_text(
        '<PAMDataset><Metadata domain="OVERVIEWS">'
        f'<MDI key="OVERVIEW_FILE">/vsicurl/{url}/overviews.tif</MDI></Metadata></PAMDataset>')
    secret = watch(outside / "secret.tif")
    _refused(lambda: _load(root, FIELD + '[map]\nfile = "ovr.tif"\n'), "ovr.tif.ovr", "not a TIFF")
    _refused(lambda: _load(root, FIELD + '[map]\nfile = "aux.tif"\n'), "aux.tif.aux.xml",
             "names another file")
    for name in ("ovr.tif", "aux.tif"):  # outside a data root, GDAL is not let near the side files
        assert np.nanmax(read_map(root / name).rates_kg_ha) == 7.0
    assert secret.untouched() and hits == []


def _zones(stem) -> None:
    with shapefile.Writer(str(stem), shapeType=shapefile.POLYGON) as w:
        w.field("RATE_KG_HA", "N", size=10, decimal=2)
        w.poly([[(X0, Y0), (X0 + 40, Y0), (X0 + 40, Y0 - 40), (X0, Y0 - 40), (X0, Y0)]])
        w.record(100.0)
    (stem.parent / (stem.name + ".prj")).write_text(pyproj.CRS.from_epsg(32632).to_wkt(version="WKT1_ESRI"))


@pytest.mark.parametrize("part", ["prj", "dbf"])
def test_a_shapefile_part_symlinked_out_of_the_root_is_refused_unopened(place, watch, part):
    """The .shp is a link to a real shapefile inside the root, so the path resolves inside; its
    ``.prj``/``.dbf`` beside the link (where a reader opens it) leads out."""
    root, outside = place
    (root / "real").mkdir()
    (root / "given").mkdir()
    _zones(root / "real" / "zones")
    _zones(outside / "other")
    for ext in ("shp", "shx", "dbf", "prj"):
        target = outside / f"other.{ext}" if ext == part else root / "real" / f"zones.{ext}"
        os.symlink(target, root / "given" / f"zones.{ext}")
    secret = watch(outside / f"other.{part}")
    _refused(lambda: _load(root, FIELD + '[map]\nfile = "given/zones.shp"\n'), "given/zones.shp",
             "outside the data root")
    boundary = '[field]\nfile = "given/zones.shp"\n[map]\nsynthetic = "uniform"\n'
    _refused(lambda: DataRoot(str(root)).scenario(boundary, "bus.toml", str(root)), "given/zones.shp",
             "outside the data root")
    assert secret.untouched()
    _load(root, FIELD + '[map]\nfile = "real/zones.shp"\n')  # the same shapefile, not linked out, loads


# ----------------------------------------------------------------------------------- /vsi paths
def test_a_vsi_path_given_by_the_user_is_refused_without_a_request(place, web):
    root, _ = place
    url, hits = web
    given = f"/vsicurl/{url}/x.tif"
    _refused(lambda: read_map(given), given, "GDAL virtual file system path")
    _refused(lambda: read_point_log(f"/vsicurl/{url}/log.gpkg"), "GDAL virtual file system path")
    _refused(lambda: Field.from_file(f"/vsicurl/{url}/field.geojson"), "GDAL virtual file system path")
    _refused(lambda: read_point_log(f"/vsizip/{root}/log.zip/log.shp"), "GDAL virtual file system path")
    assert hits == []


# --------------------------------------------------------------------------- vector signatures
def test_vector_files_open_only_as_their_extension_says(place, web):
    root, outside = place
    url, hits = web
    ogr_vrt = (f'<OGRVRTDataSource><OGRVRTLayer name="x"><SrcDataSource>/vsicurl/{url}/x.gpkg'
               '</SrcDataSource></OGRVRTLayer></OGRVRTDataSource>')
    for name in ("log.gpkg", "log.shp"):
        (root / name).write_text(ogr_vrt)
        _refused(lambda name=name: read_point_log(root / name), name, "cannot read as a vector file")
    assert hits == []


def test_a_taskdata_xml_whose_grid_file_links_out_of_the_root_is_refused_unopened(place, watch):
    """Given TASKDATA.XML rather than its folder, the reader still opens the folder's GRD .BIN."""
    root, outside = place
    from vrsim.maps.isoxml import write_isoxml

    write_isoxml(read_map(outside / "secret.tif"), str(outside / "TASKDATA"))
    (root / "task").mkdir()
    for name in os.listdir(outside / "TASKDATA"):
        target = outside / "TASKDATA" / name
        if name.upper().endswith(".BIN"):
            os.symlink(target, root / "task" / name)
        else:
            (root / "task" / name).write_bytes(target.read_bytes())
    binary = next(p for p in (outside / "TASKDATA").iterdir() if p.suffix.upper() == ".BIN")
    secret = watch(binary)
    _refused(lambda: _load(root, FIELD + '[map]\nfile = "task/TASKDATA.XML"\n'), "task/TASKDATA.XML",
             "outside the data root")
    assert secret.untouched()


def test_gdal_read_env_itself_keeps_gdal_off_the_network(web):
    """Behind the signature checks, the environment every read runs in: /vsicurl/ fetches nothing."""
    from vrsim.common import files

    url, hits = web
    with pytest.raises(rasterio.errors.RasterioIOError), rasterio.Env(**files.GDAL_READ_ENV):
        rasterio.open(f"/vsicurl/{url}/x.tif")
    assert hits == []
    with pytest.raises(rasterio.errors.RasterioIOError):  # the control: without it, GDAL goes out
        rasterio.open(f"/vsicurl/{url}/x.tif")
    assert "/x.tif" in hits


def test_pyogrio_is_imported_without_pandas_and_pandas_still_imports_after():
    """`maps.vector.ogr`: pyogrio's optional pandas (40 MB of a run's process) is not loaded with it."""
    code = ("import sys\nfrom vrsim.maps.vector import ogr\npyogrio = ogr()\n"
            "assert 'pandas' not in sys.modules and ogr() is pyogrio\n"
            "import pandas\nprint(pandas.DataFrame({'a': [1]}).shape)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.split() == ["(1,", "1)"], done.stderr
