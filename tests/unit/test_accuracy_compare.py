import json

import pytest

from vrsim.common import ScenarioError
from vrsim.services.sim import accuracy


@pytest.fixture
def library(tmp_path, monkeypatch):
    monkeypatch.setattr(accuracy, "EXPECTED", str(tmp_path / "expected.json"))
    monkeypatch.setattr(accuracy, "CHANGELOG", str(tmp_path / "CHANGELOG.md"))
    return tmp_path


def _summary(mae=2.0, within=95.0):
    s = {m: 10.0 for m in accuracy.TOLERANCES}
    s.update(mae_kg_ha=mae, within_10pct_area_pct=within, transition_time_s_mean=None)
    return s


def test_update_then_compare_passes_and_a_regression_moves(library):
    accuracy.update({"a": _summary()}, reason="first figures")
    expected = accuracy.load_expected()
    assert expected["a"]["mae_kg_ha"]["value"] == 2.0
    assert not any(c.moved for c in accuracy.compare("a", _summary(), expected))
    moved = [c for c in accuracy.compare("a", _summary(mae=4.0, within=80.0), expected) if c.moved]
    assert {c.metric for c in moved} == {"mae_kg_ha", "within_10pct_area_pct"}
    assert "MOVED" in accuracy.table(moved)


def test_null_versus_number_is_a_move(library):
    accuracy.update({"a": _summary()}, reason="x")
    s = _summary()
    s["transition_time_s_mean"] = 1.0
    moved = [c.metric for c in accuracy.compare("a", s, accuracy.load_expected()) if c.moved]
    assert moved == ["transition_time_s_mean"]


def test_update_logs_reason_and_old_and_new_figures(library):
    accuracy.update({"a": _summary()}, reason="first")
    accuracy.update({"a": _summary(mae=3.0)}, reason="gain change")
    log = (library / "CHANGELOG.md").read_text()
    assert "gain change" in log and "a mae_kg_ha: 2.0 -> 3.0" in log
    assert json.loads((library / "expected.json").read_text())["a"]["mae_kg_ha"]["value"] == 3.0


def test_update_without_reason_is_refused(library):
    with pytest.raises(ScenarioError, match="--reason"):
        accuracy.update({"a": _summary()}, reason=" ")
