"""Rate units (`maps.units`, on pint): spellings farm files use, kinds, conversions between kinds only
with a density or a seed mass, units in attribute names, and maps that state their unit or are given
one (and are refused when neither)."""

import json

import numpy as np
import pytest
import rasterio
from affine import Affine

from vrsim.common import MapError
from vrsim.maps import read_map
from vrsim.maps.units import convert_rate, map_unit, rate_kind, rate_unit, unit_in_name

LB_AC_KG_HA = 0.45359237 / 0.40468564224  # one pound per acre in kg/ha
GAL_AC_L_HA = 3.785411784 / 0.40468564224  # one US gallon per acre in L/ha


@pytest.mark.parametrize("text, unit, kind", [
    ("kg/ha", "kg/ha", "mass"), ("kg ha-1", "kg/ha", "mass"), ("lb/ac", "lb/ac", "mass"),
    ("lbs/ac", "lb/ac", "mass"), ("lb/acre", "lb/ac", "mass"), ("t/ha", "t/ha", "mass"),
    ("g/m2", "g/m2", "mass"), ("L/ha", "L/ha", "volume"), ("l/ha", "L/ha", "volume"),
    ("gal/ac", "gal/ac", "volume"), ("gallon/acre", "gal/ac", "volume"), ("mL/m2", "mL/m2", "volume"),
    ("floz/ac", "floz/ac", "volume"), ("seeds/ha", "seeds/ha", "count"), ("seeds/ac", "seeds/ac", "count")])
def test_farm_spellings_read_as_one_unit_of_a_kind(text, unit, kind):
    assert rate_unit(text) == unit and rate_kind(text) == kind


def test_conversions_within_a_kind_by_the_definitions():
    assert convert_rate(1.0, "lb/ac", "kg/ha") == pytest.approx(LB_AC_KG_HA, rel=1e-12)
    assert convert_rate(1.0, "gal/ac", "L/ha") == pytest.approx(GAL_AC_L_HA, rel=1e-12)
    assert convert_rate(1.0, "g/m2", "kg/ha") == pytest.approx(10.0)
    assert convert_rate(1.0, "t/ha", "kg/ha") == pytest.approx(1000.0)
    assert convert_rate(1.0, "mL/m2", "L/ha") == pytest.approx(10.0)
    assert convert_rate(128.0, "floz/ac", "gal/ac") == pytest.approx(1.0)
    assert convert_rate(1.0, "seeds/ac", "seeds/ha") == pytest.approx(1 / 0.40468564224)
    np.testing.assert_allclose(convert_rate([100.0, np.nan], "kg/ha", "lb/ac"), [100 / LB_AC_KG_HA, np.nan])


def test_between_kinds_only_with_a_density_or_a_seed_mass():
    assert convert_rate(10.0, "gal/ac", "kg/ha", density_kg_l=1.2) == pytest.approx(10 * GAL_AC_L_HA * 1.2,
                                                                                 rel=1e-12)
    assert convert_rate(120.0, "kg/ha", "L/ha", density_kg_l=1.2) == pytest.approx(100.0)
    # 80,000 seeds/ha of 0.35 g: 28 kg/ha
    assert convert_rate(80_000.0, "seeds/ha", "kg/ha", seed_mass_g=0.35) == pytest.approx(28.0)
    with pytest.raises(MapError, match=r"^cannot convert a volume rate \(gal/ac\) to a mass rate \(kg/ha\) "
                                       r"without the product's density \(kg/L\)$"):
        convert_rate(1.0, "gal/ac", "kg/ha")
    with pytest.raises(MapError, match=r"count rate \(seeds/ac\) .* without the product's seed mass"):
        convert_rate(1.0, "seeds/ac", "kg/ha")
    with pytest.raises(MapError, match="density_kg_l must be a number > 0, got -1.0"):
        convert_rate(1.0, "L/ha", "kg/ha", density_kg_l=-1.0)


@pytest.mark.parametrize("text, needle", [("widgets/ac", "is not a unit pint reads"),
                                          ("kg", "is not a rate (mass, volume or count per area"),
                                          ("m/s", "it is [length] / [time]"), ("", "is not a rate unit")])
def test_what_is_no_rate_unit_is_refused_naming_where(text, needle):
    with pytest.raises(MapError) as err:
        rate_unit(text, "a.toml: [map] unit")
    assert str(err.value).startswith(f"a.toml: [map] unit: {text!r}") and needle in str(err.value)


@pytest.mark.parametrize("name, unit", [
    ("Rate_lb_ac", "lb/ac"), ("Rate (lb/ac)", "lb/ac"), ("rate_kg_ha", "kg/ha"), ("RATE_KG_HA", "kg/ha"),
    ("R_gal_ac", "gal/ac"), ("RATE[L/ha]", "L/ha"), ("seeds_ac", "seeds/ac"), ("RATE", None),
    ("target_rate", None), ("AREA_HA", None), ("rx_rate", None)])
def test_units_in_attribute_names(name, unit):
    assert unit_in_name(name) == unit


def test_a_map_unit_is_stated_or_given_and_they_must_agree():
    assert map_unit("m.tif", "lbs/ac", None) == "lb/ac"
    assert map_unit("m.tif", None, "L/ha") == "L/ha" and map_unit("m.tif", "kg/ha", "kg ha-1") == "kg/ha"
    assert map_unit("m.tif", "furlongs of rate", "kg/ha") == "kg/ha"  # a unit pint cannot read: given
    with pytest.raises(MapError, match=r"^m.tif: the map does not state the unit of its rates; give it: "
                                       r"\[map\] unit = \"lb/ac\" in the scenario, or --unit lb/ac"):
        map_unit("m.tif", None, None)
    with pytest.raises(MapError, match="m.tif: the file states its rates in kg/ha \\(band unit\\), not in "
                                       "the unit given, 'lb/ac'"):
        map_unit("m.tif", "kg/ha", "lb/ac", "band unit")


def _tif(path, unit=None, tag=None):
    with rasterio.open(path, "w", driver="GTiff", width=2, height=1, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(10, 0, 500_000, 0, -10, 5_300_000)) as dst:
        dst.write(np.array([[100.0, 200.0]], np.float32), 1)
        if unit:
            dst.units = (unit,)
        if tag:
            dst.update_tags(unit=tag)
    return path


def test_a_geotiff_states_its_unit_by_band_unit_or_tag_and_is_read_in_kg_ha(tmp_path):
    g = read_map(_tif(tmp_path / "a.tif", unit="lb/ac"))
    assert (g.unit, g.map_unit) == ("kg/ha", "lb/ac")
    np.testing.assert_allclose(g.rates_kg_ha, [[100 * LB_AC_KG_HA, 200 * LB_AC_KG_HA]])
    np.testing.assert_allclose(g.in_map_unit(g.rates_kg_ha), [[100.0, 200.0]])
    info = g.info()
    assert info["rate_unit"] == "lb/ac" and info["max_rate"] == pytest.approx(200.0)
    assert info["max_rate_kg_ha"] == pytest.approx(200 * LB_AC_KG_HA)
    assert read_map(_tif(tmp_path / "b.tif", tag="t/ha")).map_unit == "t/ha"
    volume = read_map(_tif(tmp_path / "c.tif", unit="L/ha"))  # no density: held in L/ha, no prescription
    assert (volume.unit, volume.map_unit) == ("L/ha", "L/ha") and "max_rate_kg_ha" not in volume.info()
    dense = read_map(tmp_path / "c.tif", density_kg_l=1.5)
    np.testing.assert_allclose(dense.rates_kg_ha, [[150.0, 300.0]])
    with pytest.raises(MapError, match="d.tif: the map does not state the unit of its rates"):
        read_map(_tif(tmp_path / "d.tif"))
    assert read_map(tmp_path / "d.tif", unit="kg/ha").map_unit == "kg/ha"


def test_written_files_state_the_maps_unit_and_read_back_the_same(tmp_path):
    from vrsim.maps import write_map

    g = read_map(_tif(tmp_path / "a.tif", unit="lb/ac"))
    for name in ("b.tif", "b.csv", "b.geojson", "b.shp"):
        write_map(g, tmp_path / name)
        back = read_map(tmp_path / name, cell_size_m=10)
        assert back.map_unit == "lb/ac", name
        np.testing.assert_allclose(np.nanmax(back.rates_kg_ha), 200 * LB_AC_KG_HA, rtol=1e-6)
    write_map(g, tmp_path / "TASKDATA")  # ISOXML: DDI 6 in mg/m^2, read in kg/ha
    back = read_map(tmp_path / "TASKDATA")
    assert back.map_unit == "kg/ha"
    assert np.nanmax(back.rates_kg_ha) == pytest.approx(200 * LB_AC_KG_HA, rel=1e-4)


def test_zones_state_their_unit_in_the_attribute_name_or_deere_metadata(tmp_path):
    import shapefile

    def zones(stem, field):
        with shapefile.Writer(str(tmp_path / stem), shapeType=shapefile.POLYGON) as w:
            w.field(field, "N", 8, 2)
            w.poly([[(500_000, 5_300_000), (500_000, 5_300_020), (500_020, 5_300_020), (500_020, 5_300_000),
                     (500_000, 5_300_000)]])
            w.record(12.0)
        return tmp_path / f"{stem}.shp"

    assert read_map(zones("a", "Rate_lb_ac"), crs="EPSG:32632").map_unit == "lb/ac"
    plain = zones("b", "Rate")
    with pytest.raises(MapError, match="b.shp: the map does not state the unit"):
        read_map(plain, crs="EPSG:32632")
    (tmp_path / "b-Deere-Metadata.json").write_text(json.dumps(
        {"DataAttributes": [{"Name": "Rate", "Unit": "gal1ac-1"}]}))
    g = read_map(plain, crs="EPSG:32632")
    assert (g.unit, g.map_unit) == ("gal/ac", "gal/ac") and np.nanmax(g.rates_kg_ha) == pytest.approx(12.0)


def test_an_isoxml_grid_states_its_unit_by_its_ddi(tmp_path):
    from vrsim.maps import write_map

    write_map(read_map(_tif(tmp_path / "a.tif", unit="kg/ha")), tmp_path / "mass")
    mass = read_map(tmp_path / "mass")  # DDI 0006, mg/m^2
    assert mass.map_unit == "kg/ha" and np.nanmax(mass.rates_kg_ha) == pytest.approx(200.0)
    with pytest.raises(MapError, match="states its rates in kg/ha \\(its DDI\\), not in the unit given, "
                                       "'L/ha'"):
        read_map(tmp_path / "mass", unit="L/ha")
    # The same grid file under DDI 0001 (volume per area, 0.01 mm^3/m^2): 20,000 counts = 2 L/ha.
    (tmp_path / "volume").mkdir()
    for name in ("TASKDATA.XML", "GRD00001.BIN"):
        data = (tmp_path / "mass" / name).read_bytes()
        (tmp_path / "volume" / name).write_bytes(data.replace(b'A="0006"', b'A="0001"'))
    volume = read_map(tmp_path / "volume")
    assert (volume.unit, volume.map_unit) == ("L/ha", "L/ha")
    assert np.nanmax(volume.rates_kg_ha) == pytest.approx(2.0)
    assert np.nanmax(read_map(tmp_path / "volume", density_kg_l=1.25).rates_kg_ha) == pytest.approx(2.5)
