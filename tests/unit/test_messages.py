"""The message schemas of the Zenoh API: round trips, NaN as null, and errors that name the field."""

import json
import math

import numpy as np
import pytest

from vrsim.common import ServiceError
from vrsim.services.bus import messages
from vrsim.services.bus.messages import MapRate, Pose, RateSample, RunStart, ShaftState


def pose(tick=0, **changes):
    fields = dict(run_id="r1", tick=tick, time_s=0.05 * (tick + 1), x_m=678001.25, y_m=5775002.5,
                  measured_x_m=678001.3, measured_y_m=5775002.4, heading_rad=1.5707963267948966,
                  speed_m_s=2.2222222222222223, measured_speed_m_s=2.25, implement_on=True, s_m=103.75)
    fields.update(changes)
    return Pose(**fields)


def test_pose_round_trip_is_exact():
    p = pose(7)
    back = Pose.from_json(p.to_json())
    assert back == p
    assert json.loads(p.to_json())["speed_m_s"] == 2.2222222222222223  # shortest repr: no digits lost


def test_nan_travels_as_null_and_comes_back_as_nan():
    r = RateSample("r1", 3, 0.2, 1.0, 2.0, math.nan, math.inf, 0.01, 12.0, "0x3f", False,
                   [150.0, math.nan, 160.0], [0.004, 0.0, 0.006])
    doc = json.loads(r.to_json())
    assert doc["prescribed_kg_ha"] is None and doc["applied_kg_ha"] is None
    back = RateSample.from_json(r.to_json())
    assert math.isnan(back.prescribed_kg_ha) and math.isnan(back.applied_kg_ha)
    assert back.metered_kg == 0.01 and back.section_mask == "0x3f"
    assert doc["drive_rate_kg_ha"] == [150.0, None, 160.0] and doc["drive_kg"] == [0.004, 0.0, 0.006]
    assert back.drive_kg == [0.004, 0.0, 0.006] and math.isnan(back.drive_rate_kg_ha[1])


def shaft(drives) -> dict:
    return {**ShaftState("r", 1, 0.05, 50.0, 49.0, 0.04, 0.2, [50.0]).to_dict(), "drive_target_rpm": drives}


@pytest.mark.parametrize("drives, needle", [
    (50.0, "field drive_target_rpm must be an array of 1 to 128 numbers, got 50.0"),
    ([], "field drive_target_rpm must be an array of 1 to 128 numbers, got []"),
    ([1.0] * 129, "field drive_target_rpm must be an array of 1 to 128 numbers"),
    ([50.0, "1"], 'field drive_target_rpm[1] must be a number or null, got "1"'),
    ([50.0, True], "field drive_target_rpm[1] must be a number or null, got true"),
    ([[50.0]], "field drive_target_rpm[0] must be a number or null, got [50.0]"),
])
def test_a_per_drive_array_is_checked_element_by_element(drives, needle):
    """Each metering drive's values come as an array of numbers (null: NaN): anything else is refused
    naming the record, the field and the element."""
    with pytest.raises(ServiceError) as err:
        messages.decode_batch(ShaftState, json.dumps([shaft([50.0]), shaft(drives)]).encode())
    assert str(err.value).startswith("ShaftState[1]: ") and needle in str(err.value)
    back = messages.decode_batch(ShaftState, json.dumps([shaft([50, None, 49.5])]).encode())[0]
    assert back.drive_target_rpm[0] == 50.0 and type(back.drive_target_rpm[0]) is float


def test_optional_fields_stay_none():
    m = MapRate(None, None, "lb/ac", False, None, None)
    assert MapRate.from_json(m.to_json()) == m
    assert json.loads(m.to_json()) == {"rate_kg_ha": None, "rate": None, "rate_unit": "lb/ac",
                                       "inside": False, "row": None, "col": None}


def test_batch_round_trip_and_single_object_is_a_batch_of_one():
    batch = [pose(i) for i in range(5)]
    assert messages.decode_batch(Pose, messages.encode_batch(batch)) == batch
    assert messages.decode_batch(Pose, batch[0].to_json()) == batch[:1]


@pytest.mark.parametrize("doc, needle", [
    ({"tick": 1}, "missing field 'run_id'"),
    ({**pose().to_dict(), "extra_m": 1.0}, "unknown field 'extra_m'"),
    ({**pose().to_dict(), "tick": 1.5}, "field tick must be int, got 1.5"),
    ({**pose().to_dict(), "tick": True}, "field tick must be int, got true"),
    ({**pose().to_dict(), "x_m": "1"}, 'field x_m must be float or null, got "1"'),
    ({**pose().to_dict(), "implement_on": 1}, "field implement_on must be bool, got 1"),
    ([1, 2], "expected a JSON object"),
])
def test_decode_names_the_field_and_value(doc, needle):
    with pytest.raises(ServiceError) as err:
        messages.decode_batch(Pose, json.dumps(doc).encode())
    assert needle in str(err.value)


@pytest.mark.parametrize("payload, needle", [
    (b"", "empty payload"),
    (b"{not json", "not valid JSON"),
    (b"[]", "non-empty JSON array"),
    (b'"text"', "non-empty JSON array"),
])
def test_decode_refuses_malformed_payloads(payload, needle):
    with pytest.raises(ServiceError) as err:
        messages.decode_batch(ShaftState, payload)
    assert needle in str(err.value)


def test_run_start_checks_its_values():
    ok = RunStart("r", "text", "builtin:default", "/tmp", "lockstep", 1.0, 20)
    assert RunStart.from_json(ok.to_json()) == ok
    with pytest.raises(ServiceError, match="clock must be one of lockstep, realtime, got 'fast'"):
        RunStart("r", "text", "s", "/tmp", "fast", 1.0, 20)
    with pytest.raises(ServiceError, match="ticks_per_message must be within"):
        RunStart("r", "text", "s", "/tmp", "lockstep", 1.0, 0)
    with pytest.raises(ServiceError, match="speed must be within"):
        RunStart("r", "text", "s", "/tmp", "realtime", 0.0, 1)


def test_decode_points_both_forms():
    x, y, geo = messages.decode_points(b'{"x": [1, 2.5], "y": [3, 4]}')
    assert not geo and x.tolist() == [1.0, 2.5] and y.tolist() == [3.0, 4.0]
    lon, lat, geo = messages.decode_points(b'{"lat": [52.1], "lon": [11.6]}')
    assert geo and lon.tolist() == [11.6] and lat.tolist() == [52.1]


@pytest.mark.parametrize("body, needle", [
    ({"x": [1], "lat": [2]}, "got keys ['lat', 'x']"),
    ({"x": [1, 2], "y": [3]}, "x has 2 values, y 1"),
    ({"x": [1, True], "y": [3, 4]}, "non-number true"),
    ({"x": [1, "2"], "y": [3, 4]}, 'non-number "2"'),
    ({"x": [[1]], "y": [3]}, "non-number [1]"),
    ({"x": 1, "y": 3}, "x must be an array"),
    ({"lat": [91.0], "lon": [0.0]}, "point 0 (lon=0.0, lat=91.0) is not finite or out of range"),
])
def test_decode_points_refuses_bad_bodies(body, needle):
    with pytest.raises(ServiceError) as err:
        messages.decode_points(json.dumps(body).encode())
    assert needle in str(err.value)


def test_decode_points_refuses_nan_written_as_json_nan():
    # Python's json.dumps writes NaN, which is not JSON: refused where it stands.
    with pytest.raises(ServiceError, match=r"not valid JSON .*char 10"):
        messages.decode_points(b'{"x": [1, NaN], "y": [3, 4]}')


def test_encode_rates_is_a_json_array_of_map_rates():
    rate = np.array([120.5, np.nan, np.nan])
    inside = np.array([True, True, False])
    row, col = np.array([3, 4, -1]), np.array([5, 6, -1])
    doc = json.loads(messages.encode_rates(rate, rate / 2, "t/ha", inside, row, col))
    assert [MapRate.from_dict(d) for d in doc] == [MapRate(120.5, 60.25, "t/ha", True, 3, 5),
                                                   MapRate(None, None, "t/ha", True, 4, 6),
                                                   MapRate(None, None, "t/ha", False, None, None)]
    # A map not in a mass rate (a volume map without a density): its rates, no kg/ha.
    doc = json.loads(messages.encode_rates(None, rate, "gal/ac", inside, row, col))
    assert [(d["rate_kg_ha"], d["rate"], d["rate_unit"]) for d in doc] == [(None, 120.5, "gal/ac"),
                                                                           (None, None, "gal/ac"),
                                                                           (None, None, "gal/ac")]


def test_columns_are_the_batch_fields_and_refusals_are_decode_batchs():
    batch = [pose(i, x_m=float("nan") if i == 2 else 678001.25 + i) for i in range(4)]
    cols, last = messages.decode_columns(Pose, messages.encode_batch(batch), ("run_id", "tick", "x_m",
                                                                             "implement_on"))
    assert last == batch[-1] and cols["run_id"] == ["r1"] * 4 and cols["tick"].tolist() == [0, 1, 2, 3]
    assert np.isnan(cols["x_m"][2]) and cols["x_m"][3] == 678004.25 and cols["implement_on"].all()
    one, _ = messages.decode_columns(Pose, batch[0].to_json(), ("tick",))
    assert one["tick"].tolist() == [0]
    for doc, needle in [([{**pose().to_dict(), "tick": True}], "Pose[0]: field tick must be int, got true"),
                        ([pose().to_dict(), {**pose().to_dict(), "x_m": "1"}],
                         'Pose[1]: field x_m must be float or null, got "1"'),
                        ([{"tick": 1}], "Pose[0]: missing field 'run_id'"), ([], "non-empty JSON array")]:
        with pytest.raises(ServiceError) as err:
            messages.decode_columns(Pose, json.dumps(doc).encode(), ("tick", "x_m"))
        assert needle in str(err.value)
    with pytest.raises(ServiceError, match="more than 2 records, refused before parsing"):
        messages.decode_columns(Pose, messages.encode_batch(batch[:3]), ("tick",), max_len=2)
