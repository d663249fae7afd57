"""Issue 41's third round, the bus's parts that need no bus: how many points a ``map/rate`` reply
may carry under the router's message limit (from the reply's own encoding), which user controller
files the controller service lists at start, and the check that a file binds its class before any of
it runs. The same over real processes: ``tests/integration/test_bus_trust_round3.py``."""

from __future__ import annotations

import os

import numpy as np
import pytest

from vrsim.common import ControllerError, ServiceError
from vrsim.controller.kinds.python import check_defines_class
from vrsim.maps.units import MAX_UNIT_CHARS
from vrsim.services.bus import messages
from vrsim.services.bus.controller import _allowed_files
from vrsim.services.bus.security import MAX_BODY_BYTES, MESSAGE_OVERHEAD_BYTES

ROUTER_MESSAGE_BYTES = MAX_BODY_BYTES + MESSAGE_OVERHEAD_BYTES  # what the router reassembles at most
LONGEST_FLOAT = -2.2250738585072014e-308  # 24 characters in orjson's shortest round trip


def _reply(n: int, unit: str, rate: float, row: int, col: int) -> bytes:
    return messages.encode_rates(np.full(n, rate), np.full(n, rate), unit, np.ones(n, bool),
                                 np.full(n, row), np.full(n, col))


# ------------------------------------------------------------------------------- map/rate replies
def test_a_reply_at_the_point_limit_lies_well_under_the_routers_message_limit():
    """Every point at its longest (24-character floats, 10-digit row and column, a 64-character
    unit): the reply of `MAX_POINTS` is under `MAX_RATES_REPLY_BYTES`, three quarters of the router's."""
    unit = "g" * (MAX_UNIT_CHARS - 3) + "/ha"
    n = 1_000
    per_point = (len(_reply(n, unit, LONGEST_FLOAT, 9_999_999_999, 9_999_999_999)) - 1) / n
    assert per_point == messages._RATE_POINT_BYTES + MAX_UNIT_CHARS == 199
    assert messages.max_points(unit) == messages.MAX_POINTS == 250_000
    assert messages.MAX_POINTS * per_point <= messages.MAX_RATES_REPLY_BYTES <= 0.75 * ROUTER_MESSAGE_BYTES
    # a kg/ha map's reply, full-precision rates: ~115 bytes a point
    typical = (len(_reply(n, "kg/ha", 175.41828117237952, 123, 456)) - 1) / n
    assert 110 < typical < 120


def test_a_unit_whose_json_is_long_takes_fewer_points():
    """Characters that JSON escapes (a control character is six bytes) or that take several bytes in
    UTF-8 make each point longer: the limit for that map shrinks so the reply still fits."""
    unit = "kg" + "\x1c" * (MAX_UNIT_CHARS - 5) + "m-2"
    limit = messages.max_points(unit)
    assert limit < messages.MAX_POINTS
    n = 1_000
    per_point = (len(_reply(n, unit, LONGEST_FLOAT, 9_999_999_999, 9_999_999_999)) - 1) / n
    assert limit * per_point <= messages.MAX_RATES_REPLY_BYTES


def _body(n: int) -> bytes:
    xs = ",".join(["1.5"] * n)
    return f'{{"x": [{xs}], "y": [{xs}]}}'.encode()


def test_a_body_over_the_point_limit_is_refused_before_parsing_naming_the_limit():
    with pytest.raises(ServiceError, match=r"more than 250,000 points in one query .* send batches\)"):
        messages.decode_points(_body(messages.MAX_POINTS + 1))
    x, _, _ = messages.decode_points(_body(messages.MAX_POINTS))
    assert len(x) == messages.MAX_POINTS


# --------------------------------------------------------------------------- user controller files
CLASS = "class MyController:\n    pass\n"


def _write(path, text: str) -> str:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as fh:
        fh.write(text)
    return str(path)


def test_only_the_python_files_directly_in_a_folder_at_start_are_allowed(tmp_path):
    folder = tmp_path / "ctl"
    mine = _write(folder / "mine.py", CLASS)
    _write(folder / "sub" / "deep.py", CLASS)
    _write(folder / "notes.txt", CLASS)
    elsewhere = _write(tmp_path / "elsewhere" / "target.py", CLASS)
    os.symlink(elsewhere, folder / "link.py")
    one = _write(tmp_path / "one" / "single.py", CLASS)
    allowed = _allowed_files((str(folder), one))
    # the link is allowed as the file it named at start
    assert allowed == {mine: str(folder), elsewhere: str(folder), one: one}
    _write(folder / "later.py", CLASS)  # added after the start: not listed
    assert str(folder / "later.py") not in allowed
    with pytest.raises(ServiceError, match=r"--allow-user-code .*missing: no such file or folder"):
        _allowed_files((str(tmp_path / "missing"),))


@pytest.mark.parametrize("text", [
    CLASS,
    "import numpy as np\nif True:\n    class MyController:\n        pass\n",
    "try:\n    from x import Base as MyController\nexcept ImportError:\n    MyController = None\n",
    "MyController: type = object\n",
])
def test_a_file_that_binds_the_class_at_its_top_level_passes(tmp_path, text):
    check_defines_class(_write(tmp_path / "c.py", text), "MyController")


@pytest.mark.parametrize("text, needle", [
    ("open('marker', 'w')\nclass Other:\n    pass\n", "no class 'MyController' at its top level"),
    ("def make():\n    class MyController:\n        pass\n", "no class 'MyController' at its top level"),
    ("class MyController(\n", "c.py:1: cannot be loaded: SyntaxError"),
    ("x = 1\0\n", "cannot be loaded"),
])
def test_a_file_without_the_class_is_refused_and_nothing_of_it_runs(tmp_path, monkeypatch, text, needle):
    path = _write(tmp_path / "c.py", text)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ControllerError, match=needle):
        check_defines_class(path, "MyController")
    assert not os.path.exists(tmp_path / "marker")


def test_a_controller_source_over_its_cap_or_not_a_file_is_refused(tmp_path):
    big = _write(tmp_path / "big.py", CLASS + "#" * (1024 * 1024))
    with pytest.raises(ControllerError, match="over the 1 MB cap"):
        check_defines_class(big, "MyController")
    os.mkfifo(tmp_path / "fifo.py")
    with pytest.raises(ControllerError, match="is a FIFO, not a regular file"):
        check_defines_class(str(tmp_path / "fifo.py"), "MyController")


# ------------------------------------------------------------------------ waiting for scenario/start
def test_vrsim_query_waits_for_scenario_start_as_long_as_accepting_a_run_may_take():
    """scenario/start replies once the world is built (at most `BUILD_TIMEOUT_S`) and the services and
    a user's controller file are checked: `vrsim query` (its default), `serve all SCENARIO` and the web
    page wait `ACCEPT_TIMEOUT_S`, more than all of that; any other key answers at once."""
    from vrsim.services.bus import scenario
    from vrsim.services.bus.config import ACCEPT_TIMEOUT_S, QUERY_TIMEOUT_S, Keys
    from vrsim.services.cli.query import _default_timeout

    accepting = scenario.BUILD_TIMEOUT_S + scenario.CHECK_TIMEOUT_S + 3 * scenario.STATUS_TIMEOUT_S
    assert ACCEPT_TIMEOUT_S >= 1.25 * accepting
    keys = Keys()
    assert _default_timeout("vrsim/scenario/start", keys) == ACCEPT_TIMEOUT_S
    assert _default_timeout("vrsim/scenario/status", keys) == QUERY_TIMEOUT_S == 10.0
