"""Gains: the paper's printed numbers and formulas, textbook Ziegler-Nichols, configuration checks."""

import pytest

from vrsim.common import ControllerError
from vrsim.controller import (
    ControllerConfig,
    PidGains,
    PlantParams,
    liang2013,
    paper_gains,
    resolve_gains,
    ziegler_nichols,
)


def test_paper_formulas_give_its_printed_numbers_to_their_last_digit():
    f = liang2013.formula_coefficients()
    # the paper truncates (B = 0.574272 is printed 0.5742): allow one unit of the last printed digit
    for name, printed, unit in (("Kp", 0.573, 1e-3), ("Ki", 0.1848, 1e-4), ("Kd", 0.0011, 1e-4),
                                ("A", 0.6795, 1e-4), ("B", 0.5742, 1e-4), ("C", 0.0006, 1e-4)):
        assert abs(f[name] - printed) < unit, name


def test_paper_pid_is_the_printed_a_b_c_exactly():
    assert paper_gains("PID").incremental(0.05) == pytest.approx((0.6795, 0.5742, 0.0006), rel=1e-12)
    assert paper_gains("PI").incremental(0.05) == pytest.approx((0.573 * 1.1848, 0.573, 0.0), rel=1e-12)
    assert paper_gains("P").kp == 0.573


def test_textbook_ziegler_nichols_table():
    ku, tu = 0.955, 0.31
    assert ziegler_nichols("P", ku, tu) == PidGains(0.5 * ku)
    pi = ziegler_nichols("PI", ku, tu)
    assert pi.kp == pytest.approx(0.45 * ku) and pi.kp / pi.ki == pytest.approx(tu / 1.2)
    pid = ziegler_nichols("PID", ku, tu)
    assert pid.kp == pytest.approx(0.573) and pid.kp / pid.ki == pytest.approx(tu / 2)
    assert pid.kd / pid.kp == pytest.approx(tu / 8)
    # the textbook derivative coefficient Kp Td / T is 0.444, the paper's C is 0.0006
    assert pid.incremental(0.05)[2] == pytest.approx(0.573 * 0.31 / 8 / 0.05)


def test_incremental_round_trip():
    g = PidGains(0.4, 1.7, 0.013)
    back = PidGains.from_incremental(*g.incremental(0.05), 0.05)
    assert (back.kp, back.ki, back.kd) == pytest.approx((g.kp, g.ki, g.kd), rel=1e-12)


def test_manual_and_relay_sources():
    manual = ControllerConfig(kind="PI", gains="manual", kp=0.2, ki=1.0)
    assert resolve_gains(manual) == PidGains(0.2, 1.0, 0.0)
    relay = resolve_gains(ControllerConfig(kind="P", gains="relay"), PlantParams())
    assert 0.4 < relay.kp < 0.6      # 0.5 Ku with the relay's Ku estimate near 0.955


@pytest.mark.parametrize("kwargs,field", [
    ({"kind": "PD"}, "kind"), ({"form": "velocity"}, "form"), ({"gains": "magic"}, "gains"),
    ({"kp": 0.5}, "kp"), ({"gains": "manual"}, "kp"), ({"gains": "manual", "kp": -1.0}, "kp"),
    ({"gains": "manual", "kind": "P", "kp": 0.5, "ki": 1.0}, "ki"),
    ({"gains": "manual", "kind": "PI", "kp": 0.5, "kd": 0.1}, "kd"),
    ({"derivative_on_measurement": "yes"}, "derivative_on_measurement"),
])
def test_bad_config_names_the_field(kwargs, field):
    with pytest.raises(ControllerError, match=field):
        ControllerConfig(**kwargs)
