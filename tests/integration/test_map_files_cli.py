"""`vrsim map` on the files vrsim writes for GIS and terminals, through the real executable: a signed
difference raster is inspected, not refused; ISOXML is written into a folder and never over an
earlier export."""

import json

import numpy as np
from affine import Affine

from tests.integration.test_map_cli import KG_HA, TIF, vrsim
from vrsim.maps import Grid, read_map, write_map


def test_info_accepts_a_difference_raster_and_refuses_negative_rates(tmp_path):
    rates = np.full((4, 5), 12.0)
    rates[1, 2] = -64.5
    transform = Affine(10, 0, 500_000, 0, -10, 5_300_050)
    write_map(Grid(rates, transform, "EPSG:32632", product="applied minus prescribed",
                   quantity="difference"), tmp_path / "error.tif")
    p = vrsim("info", tmp_path / "error.tif", "--json")
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    assert info["quantity"] == "difference" and info["min_rate_kg_ha"] == -64.5
    write_map(Grid(rates, transform, "EPSG:32632"), tmp_path / "rx.tif")
    p = vrsim("info", tmp_path / "rx.tif")
    assert p.returncode == 2 and "negative rate -64.5 kg/ha" in p.stderr and "Traceback" not in p.stderr


def test_convert_to_isoxml_needs_a_folder_and_never_overwrites(tmp_path):
    p = vrsim("convert", TIF, *KG_HA, tmp_path / "a.xml")
    assert p.returncode == 2 and "written as a TASKDATA folder" in p.stderr
    assert list(tmp_path.iterdir()) == []
    p = vrsim("convert", TIF, *KG_HA, tmp_path / "TASKDATA")
    assert p.returncode == 0, p.stderr
    first = (tmp_path / "TASKDATA" / "GRD00001.BIN").read_bytes()
    p = vrsim("convert", TIF, *KG_HA, tmp_path / "TASKDATA" / "TASKDATA.XML")
    assert p.returncode == 2 and "does not overwrite" in p.stderr
    assert (tmp_path / "TASKDATA" / "GRD00001.BIN").read_bytes() == first
    back = read_map(tmp_path / "TASKDATA")
    assert back.crs.to_epsg() == 4326
    assert np.nanmax(back.rates_kg_ha) == np.nanmax(read_map(TIF, unit="kg/ha").rates_kg_ha)
