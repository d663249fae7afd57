"""A spinner's steps on per side (`messages.RateSample.side_steps_on`): left out of a record where the
machine does not step (the records as before, byte for byte), checked element by element when they come,
stored by the monitor and rebuilt as the run's (ticks, 2) control array, a record that does not fit the
run's machine named. (The monitor's report of a stepping spinner over a real bus: tests/integration.)"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.unit.test_monitor_integrity import records, start
from vrsim.common import ServiceError
from vrsim.services.bus import messages
from vrsim.services.bus.monitor import MonitorStore


def _rate(steps=None) -> messages.RateSample:
    return messages.RateSample("r", 3, 0.15, 1.0, 2.0, 200.0, 199.0, 0.04, 24.0, "0x3", True, [200.0, 200.0],
                               [0.02, 0.02], steps)


def test_a_record_without_steps_leaves_the_field_out_and_one_with_them_round_trips():
    plain = json.loads(messages.encode_batch([_rate()]))[0]
    assert "side_steps_on" not in plain and "side_steps_on" not in json.loads(_rate().to_json())
    assert messages.RateSample.from_dict(plain).side_steps_on is None
    both = messages.encode_batch([_rate(), _rate([4, 1])])
    assert [r.side_steps_on for r in messages.decode_batch(messages.RateSample, both)] == [None, [4, 1]]
    columns, last = messages.decode_columns(messages.RateSample, both, ("metered_kg",))
    assert columns["metered_kg"].tolist() == [0.04, 0.04] and last.side_steps_on == [4, 1]


@pytest.mark.parametrize("steps, needle", [
    ([4, 17], "field side_steps_on[1] must be an integer in [0, 16], got 17"),
    ([-1, 2], "field side_steps_on[0] must be an integer in [0, 16], got -1"),
    ([True, 2], "field side_steps_on[0] must be an integer in [0, 16], got true"),
    ([2.0, 2], "field side_steps_on[0] must be an integer in [0, 16], got 2.0"),
    ([2], "field side_steps_on must be an array of 2 integers, got [2]"),
    ("4,4", 'field side_steps_on must be an array of 2 integers, got "4,4"'),
])
def test_bad_steps_are_refused_naming_record_field_and_element(steps, needle):
    doc = [_rate().to_dict(), {**_rate().to_dict(), "side_steps_on": steps}]
    with pytest.raises(ServiceError) as err:
        messages.decode_batch(messages.RateSample, json.dumps(doc).encode())
    assert str(err.value) == f"RateSample[1]: {needle}"
    with pytest.raises(ServiceError, match=r"^RateSample\[1\]: "):
        messages.decode_columns(messages.RateSample, json.dumps(doc).encode(), ("metered_kg",))


def _store(tmp_path, steps) -> MonitorStore:
    store = MonitorStore(str(tmp_path / "m.sqlite"))
    store.add_run(start("r"))
    recs = records("r", range(len(steps)))
    for rate, s in zip(recs["rate"], steps, strict=True):
        rate.side_steps_on = s
    for table, batch in recs.items():
        store.add(table, batch)
    return store


def test_the_steps_are_stored_and_rebuilt_as_the_runs_control_array(tmp_path):
    store = _store(tmp_path, [[4, 4], [3, 4], [0, 2], [1, 0]])
    _, control = store.arrays("r", sections=2, drives=1, side_steps=4)
    assert control["side_steps_on"].dtype == np.int64
    assert control["side_steps_on"].tolist() == [[4, 4], [3, 4], [0, 2], [1, 0]]
    assert [r.side_steps_on for r in store.records("rate", "r", 0, 4)] == [[4, 4], [3, 4], [0, 2], [1, 0]]


def test_a_run_without_steps_has_no_control_array_and_its_records_none(tmp_path):
    store = _store(tmp_path, [None] * 3)
    _, control = store.arrays("r", sections=1, drives=1)
    assert "side_steps_on" not in control
    assert [r.side_steps_on for r in store.records("rate", "r", 0, 3)] == [None] * 3


@pytest.mark.parametrize("steps, side_steps, needle", [
    ([[4, 4], [3, 5]], 4, "tick 1: side_steps_on[1] is 5, the machine's sides have 4 steps"),
    ([[4, 4], None, [2, 2]], 4, "tick 1: side_steps_on left out, other records hold it"),
    ([[1, 1], [1, 0]], 1, "tick 0: side_steps_on held, but the machine does not shorten its sides in steps"),
])
def test_steps_that_do_not_fit_the_runs_machine_are_named(tmp_path, steps, side_steps, needle):
    store = _store(tmp_path, steps)
    with pytest.raises(ServiceError) as err:
        store.arrays("r", sections=2, drives=1, side_steps=side_steps)
    assert str(err.value) == f"r: rate records: {needle}"
