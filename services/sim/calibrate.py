"""The operator's calibration of a meter, simulated: what `vrsim calibrate` runs.

Every terminal has a calibration routine for a granular meter (a spreader-constant or "rotor test"):
with the gate over a bucket, the meter turns a set number of revolutions, the operator weighs the
catch and types the weight in; the terminal divides it by the revolutions and keeps the result as the
meter constant ``kg_per_rev``. Simulated here with what the scenario knows and the terminal does not:

- the product per revolution is the product's true constant with its flow variability
  (`vehicle.product`), on revolutions of their own random stream (a calibration's revolutions are not
  the field's);
- the scale reads the catch with a random error, normal with standard deviation ``scale_error_g``.

The constant measured is ``weighed / revolutions``; it is what ``[implement] kg_per_rev`` should say.
The scenario states the truth relative to the configured constant (``[product] calibration_error_pct``:
true = configured x (1 + error / 100)), so a new configured constant alone would move the truth with
it: the same meter, recalibrated, keeps its true constant and has what is left of the error against the
new one, ``100 (true / measured - 1)``. Both settings are printed to paste together.
Its error is the scale's (``scale_error_g / revolutions`` per revolution) and the flow variability's
mean over the revolutions (``flow_cv_pct / sqrt(revolutions)``): more revolutions, a better constant.
In this model the product per revolution does not depend on the shaft's speed, so the test speed sets
only how long the test takes. Pure and seeded by the scenario's seed: the same scenario and arguments
give the same measurement.

A liquid product on a sprayer (`LiquidCalibration`): the *catch test* calibrates the flow meter's
pulses per litre. The boom sprays the product at the nozzles' reference 3 bar for ``seconds`` (each
nozzle its water rating times ``sqrt(1 / SG)``, `vehicle.sprayer.density_flow_factor`) while the terminal
counts the meter's pulses; the operator catches each nozzle's output in a jug and reads it (each
reading with a random error, normal with standard deviation ``jug_error_ml``; one nozzle's catch
alone would carry the nozzles' spread, so all are caught), and the meter's constant measured is
``pulses / litres caught`` (a tank volume test is the same division with the litres read off the
tank's gauge). The meter's truth is ``[implement] flow_meter_error_pct`` against the configured constant, so
the same meter recalibrated is left with ``100 (true / measured - 1)``; both settings are printed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from vrsim.common import ScenarioError, VrsimError
from vrsim.common.checks import in_range
from vrsim.maps.units import shown_text
from vrsim.services.sim.machines import Machine
from vrsim.services.sim.machines.registry import MACHINES
from vrsim.services.sim.machines.sprayer import check_liquid
from vrsim.services.sim.scenario import Scenario, scenario_file
from vrsim.vehicle.product import metered_kg
from vrsim.vehicle.sprayer import REF_PRESSURE_BAR

DEFAULT_REVOLUTIONS = 50
DEFAULT_SCALE_ERROR_G = 20.0    # a platform scale for a 20-30 kg catch, read to +-20 g
MAX_REVOLUTIONS = 100_000
MAX_SCALE_ERROR_G = 100_000.0
_CATCH_STREAM = 0xCA1_0001      # the test's revolutions: not the field's (`vehicle.product`)
_SCALE_STREAM = 0xCA1_0002      # the scale's error
DEFAULT_CATCH_S = 60.0          # a minute's catch, as the nozzle charts give L/min
DEFAULT_JUG_ERROR_ML = 10.0     # a 1-2 L measuring jug read to +-10 mL
MAX_CATCH_S = 3600.0
MAX_JUG_ERROR_ML = 100_000.0   # the jugs' bound, in their unit, as the scale's


def _as_written(constant: float) -> float:
    """A measured constant as the settings write it (6 significant digits)."""
    return float(f"{constant:.6g}")


def _change_pct(measured: float, configured: float) -> float:
    """A measured constant against the configured one, %."""
    return 100.0 * (measured / configured - 1.0)


def _error_left_pct(true: float, measured: float) -> float:
    """The error the same meter has left once `measured` is configured (as written), %."""
    return 100.0 * (true / _as_written(measured) - 1.0)


def _rounded_pct(pct: float) -> float:
    """A percentage as the settings write it: 3 decimals, never -0."""
    return round(pct, 3) + 0.0


@dataclass(frozen=True)
class Calibration:
    """The outcome of a simulated calibration test.

    Attributes
    ----------
    scenario : str
        The scenario's name.
    form : str
        The product's form.
    revolutions : int
        Shaft revolutions turned into the bucket.
    test_shaft_rpm : float
        The shaft's speed during the test, rpm (the middle of its range).
    duration_s : float
        How long the test turns the shaft, s.
    scale_error_g : float
        Standard deviation of the scale's reading, g.
    configured_kg_per_rev : float
        The scenario's ``[implement] kg_per_rev``, kg/rev.
    caught_kg : float
        Product in the bucket, kg (the simulation's truth).
    weighed_kg : float
        What the scale read, kg.
    measured_kg_per_rev : float
        ``weighed_kg / revolutions``, kg/rev: the constant to configure.
    true_kg_per_rev : float
        What the product really gives per revolution on average, kg/rev (the simulation's truth).
    """

    scenario: str
    form: str
    revolutions: int
    test_shaft_rpm: float
    duration_s: float
    scale_error_g: float
    configured_kg_per_rev: float
    caught_kg: float
    weighed_kg: float
    measured_kg_per_rev: float
    true_kg_per_rev: float

    @property
    def change_pct(self) -> float:
        """The measured constant against the configured one, %."""
        return _change_pct(self.measured_kg_per_rev, self.configured_kg_per_rev)

    @property
    def remaining_error_pct(self) -> float:
        """The true constant against the measured one, %: ``[product] calibration_error_pct`` once the
        measured constant is configured (rounded as `settings` writes it)."""
        return _error_left_pct(self.true_kg_per_rev, self.measured_kg_per_rev)

    @property
    def settings(self) -> dict[str, float]:
        """The scenario keys to set after the test (dotted, as ``--set`` takes them): the measured
        constant and the error the same meter has left against it."""
        return {"implement.kg_per_rev": _as_written(self.measured_kg_per_rev),
                "product.calibration_error_pct": _rounded_pct(self.remaining_error_pct)}

    def text(self, units: str = "metric") -> str:
        """What `vrsim calibrate` prints, its weights in `units` (the scenario's keys as they are set)."""
        value = f"{self.measured_kg_per_rev:.6g}"
        kg, error = self.settings.values()
        return "\n".join([
            f"Calibration of {self.scenario} ({self.form}): {self.revolutions} revolutions at "
            f"{self.test_shaft_rpm:.0f} rpm ({self.duration_s:.0f} s), the catch weighed on a scale "
            f"of +-{shown_text(self.scale_error_g, 'g', units, '.3g')}.",
            f"  Weighed {shown_text(self.weighed_kg, 'kg', units, '.3f')}: {value} kg/rev measured against "
            f"{self.configured_kg_per_rev:g} kg/rev configured ({self.change_pct:+.2f} %).",
            f"  Put in the scenario: [implement] kg_per_rev = {kg:.6g}; the same meter's true "
            f"{self.true_kg_per_rev:.6g} kg/rev then leaves [product] calibration_error_pct = {error:g}.",
            "  Or run with: " + " ".join(f"--set {k}={v:g}" for k, v in self.settings.items()),
        ])


def calibrate(scenario: Scenario, revolutions: int = DEFAULT_REVOLUTIONS,
              scale_error_g: float = DEFAULT_SCALE_ERROR_G, seconds: float = DEFAULT_CATCH_S,
              jug_error_ml: float = DEFAULT_JUG_ERROR_ML) -> Calibration | LiquidCalibration:
    """Simulate the calibration test of `scenario`'s meter for its product's form: a granular meter's
    (`revolutions`, `scale_error_g`), a sprayer's catch test (`seconds`, `jug_error_ml`).

    Raises
    ------
    VrsimError
        `revolutions` or `scale_error_g` out of range, naming the option and its value.
    ScenarioError
        A product of another form than the machine meters (`Machine.product_form`: a liquid product
        on a granular meter, a granular one on a sprayer), naming the file.
    """
    if isinstance(revolutions, bool) or not isinstance(revolutions, int) \
            or not 1 <= revolutions <= MAX_REVOLUTIONS:
        raise VrsimError(f"--revolutions {revolutions!r}: must be a whole number in [1, {MAX_REVOLUTIONS}]")
    if not in_range(scale_error_g, 0.0, MAX_SCALE_ERROR_G):
        raise VrsimError(f"--scale-error-g {scale_error_g!r}: must be a number of grams in "
                         f"[0, {MAX_SCALE_ERROR_G:g}]")
    form, kind = scenario.product.form, scenario.implement.kind
    meters = MACHINES[kind].product_form   # the form the machine's meter meters picks its test
    if form != meters:
        raise ScenarioError(f"{scenario_file(scenario)}: [product] form {form!r}: "
                            f"{_form_refused(form, kind)}, got kind {kind!r}")
    return _TESTS[meters].run(scenario, revolutions=revolutions, scale_error_g=scale_error_g,
                              seconds=seconds, jug_error_ml=jug_error_ml)


def _form_refused(form: str, kind: str) -> str:
    """Why a `form` product cannot be calibrated on a machine of `kind`: on a machine of the usual
    (granular) form, the kinds its own test needs; on another, what that machine meters."""
    meters = MACHINES[kind].product_form
    if meters != Machine.product_form:
        test = _TESTS[meters]
        return f"a {kind} meters a {test.product} (its {test.name} calibrates {test.calibrates})"
    owners = " or ".join(f'"{k}"' for k, cls in MACHINES.items() if cls.product_form == form)
    return f"its calibration (a {_TESTS[form].name}) needs [implement] kind = {owners}"


def _granular(scenario: Scenario, revolutions: int, scale_error_g: float, **_) -> Calibration:
    """A granular meter's test: `revolutions` whole turns into a bucket, weighed (the other tests'
    options left)."""
    imp, product, seed = scenario.implement, scenario.product, scenario.seed
    caught_kg = float(metered_kg(np.array([float(revolutions)]), imp.kg_per_rev, product, seed,
                                 stream=_CATCH_STREAM)[0][0])
    reading_g = np.random.default_rng([seed, _SCALE_STREAM]).normal(0.0, 1.0) * scale_error_g
    weighed_kg = caught_kg + reading_g / 1000.0
    if weighed_kg <= 0:
        raise VrsimError(f"--scale-error-g {scale_error_g!r}: the scale read {weighed_kg:.3f} kg for a "
                         f"{caught_kg:.3f} kg catch; weigh more revolutions or on a finer scale")
    test_rpm = (imp.shaft_rpm_min + imp.shaft_rpm_max) / 2.0
    return Calibration(
        scenario=scenario.name, form=product.form, revolutions=revolutions, test_shaft_rpm=test_rpm,
        duration_s=60.0 * revolutions / test_rpm, scale_error_g=float(scale_error_g),
        configured_kg_per_rev=imp.kg_per_rev, caught_kg=caught_kg, weighed_kg=weighed_kg,
        measured_kg_per_rev=weighed_kg / revolutions, true_kg_per_rev=product.true_kg_per_rev(imp.kg_per_rev))


@dataclass(frozen=True)
class LiquidCalibration:
    """The outcome of a sprayer's catch test (see the module docstring).

    Attributes
    ----------
    scenario : str
    seconds : float
        How long the boom sprayed, s.
    nozzles : int
        Nozzles on the boom.
    jug_error_ml : float
        Standard deviation of the jug's reading, mL.
    configured_pulses_per_l : float
        The scenario's ``[implement] flow_meter_pulses_per_l``.
    pulses : float
        Whole pulses the meter counted.
    caught_l, read_l : float
        The jugs' catch, L (the simulation's truth), and what they read together.
    measured_pulses_per_l : float
        ``pulses / read_l``: the constant to configure.
    true_pulses_per_l : float
        The meter's true constant (the simulation's truth).
    """

    scenario: str
    seconds: float
    nozzles: int
    jug_error_ml: float
    configured_pulses_per_l: float
    pulses: float
    caught_l: float
    read_l: float
    measured_pulses_per_l: float
    true_pulses_per_l: float

    @property
    def change_pct(self) -> float:
        """The measured constant against the configured one, %."""
        return _change_pct(self.measured_pulses_per_l, self.configured_pulses_per_l)

    @property
    def settings(self) -> dict[str, float]:
        """The scenario keys to set after the test (dotted): the measured constant and the error the same
        meter has left against it (``flow_meter_error_pct``: it reads this much more than flows)."""
        return {"implement.flow_meter_pulses_per_l": _as_written(self.measured_pulses_per_l),
                "implement.flow_meter_error_pct": _rounded_pct(_error_left_pct(self.true_pulses_per_l,
                                                                               self.measured_pulses_per_l))}

    def text(self, units: str = "metric") -> str:
        """What `vrsim calibrate` prints, its pressure and volumes in `units` (the scenario's keys as
        they are set)."""
        ppl, error = self.settings.values()
        return "\n".join([
            f"Calibration of {self.scenario} (liquid, flow meter): the boom sprayed {self.seconds:g} s at "
            f"{shown_text(REF_PRESSURE_BAR, 'bar', units, '.3g')}, each of its {self.nozzles} nozzles caught "
            f"in a jug read to +-{shown_text(self.jug_error_ml, 'mL', units, '.3g')}.",
            f"  Jugs {shown_text(self.read_l, 'L', units, '.3f')} together, the meter {self.pulses:.0f} "
            "pulses: "
            f"{ppl:g} pulses/L measured against {self.configured_pulses_per_l:g} configured "
            f"({self.change_pct:+.2f} %).",
            f"  Put in the scenario: [implement] flow_meter_pulses_per_l = {ppl:g}; the same meter's true "
            f"{self.true_pulses_per_l:.6g} pulses/L then leaves flow_meter_error_pct = {error:g}.",
            "  Or run with: " + " ".join(f"--set {k}={v:g}" for k, v in self.settings.items()),
        ])


def _liquid(scenario: Scenario, seconds: float, jug_error_ml: float, **_) -> LiquidCalibration:
    """A sprayer's catch test: the boom at 3 bar for `seconds`, each nozzle into a jug, the pulses counted
    (the other tests' options left)."""
    if not in_range(seconds, 0.0, MAX_CATCH_S, lo_open=True):
        raise VrsimError(f"--seconds {seconds!r}: must be a number of seconds in (0, {MAX_CATCH_S:g}]")
    if not in_range(jug_error_ml, 0.0, MAX_JUG_ERROR_ML):
        raise VrsimError(f"--jug-error-ml {jug_error_ml!r}: must be a number of millilitres in "
                         f"[0, {MAX_JUG_ERROR_ML:g}]")
    product = check_liquid(scenario)
    imp, seed = scenario.implement, scenario.seed
    spec = imp.machine
    nozzles = spec.nozzle_count(imp.width_m)
    # Each nozzle gives its rated flow of the product at 3 bar; its flow variability over the boom's litres.
    nominal_l = nozzles * spec.rated_flow_l_min(product.density_kg_l) * seconds / 60.0
    caught_l = float(metered_kg(np.array([nominal_l]), 1.0, scenario.product, seed,
                                stream=_CATCH_STREAM)[0][0])
    misread_ml = np.random.default_rng([seed, _SCALE_STREAM]).normal(0.0, 1.0, nozzles) * jug_error_ml
    read_l = caught_l + float(misread_ml.sum()) / 1000.0
    if read_l <= 0:
        raise VrsimError(f"--jug-error-ml {jug_error_ml!r}: the jugs read {read_l * 1000:.0f} mL for a "
                         f"{caught_l * 1000:.0f} mL catch; catch longer or read finer jugs")
    pulses = float(spec.meter.pulses(caught_l))
    return LiquidCalibration(
        scenario=scenario.name, seconds=float(seconds), nozzles=nozzles, jug_error_ml=float(jug_error_ml),
        configured_pulses_per_l=spec.flow_meter_pulses_per_l, pulses=pulses, caught_l=caught_l, read_l=read_l,
        measured_pulses_per_l=pulses / read_l,
        true_pulses_per_l=spec.flow_meter_pulses_per_l * spec.meter.gain)


@dataclass(frozen=True)
class _Test:
    """A calibration test, for the form of product a machine meters (`Machine.product_form`)."""

    name: str          # what the operator calls it
    calibrates: str    # what it measures
    product: str       # the product, as a message names it
    run: Callable      # (scenario, revolutions=, scale_error_g=, seconds=, jug_error_ml=) -> the outcome


_TESTS = {"granular": _Test("rotor test", "the meter constant", "granular product", _granular),
          "liquid": _Test("catch test", "the flow meter", "liquid", _liquid)}
