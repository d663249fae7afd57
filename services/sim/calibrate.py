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

One calibration per product form (`CALIBRATIONS`): a granular meter's here; a liquid product's
(a sprayer's catch or tank test) belongs with the sprayer machine kind.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common import ScenarioError, VrsimError
from common.checks import in_range
from services.sim.scenario import Scenario, scenario_file
from vehicle.product import metered_kg

DEFAULT_REVOLUTIONS = 50
DEFAULT_SCALE_ERROR_G = 20.0    # a platform scale for a 20-30 kg catch, read to +-20 g
MAX_REVOLUTIONS = 100_000
MAX_SCALE_ERROR_G = 100_000.0
_CATCH_STREAM = 0xCA1_0001      # the test's revolutions: not the field's (`vehicle.product`)
_SCALE_STREAM = 0xCA1_0002      # the scale's error


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
        return 100.0 * (self.measured_kg_per_rev / self.configured_kg_per_rev - 1.0)

    @property
    def remaining_error_pct(self) -> float:
        """The true constant against the measured one, %: ``[product] calibration_error_pct`` once the
        measured constant is configured (rounded as `settings` writes it)."""
        return 100.0 * (self.true_kg_per_rev / float(f"{self.measured_kg_per_rev:.6g}") - 1.0)

    @property
    def settings(self) -> dict[str, float]:
        """The scenario keys to set after the test (dotted, as ``--set`` takes them): the measured
        constant and the error the same meter has left against it."""
        return {"implement.kg_per_rev": float(f"{self.measured_kg_per_rev:.6g}"),
                "product.calibration_error_pct": round(self.remaining_error_pct, 3) + 0.0}   # no -0

    def text(self) -> str:
        """What `vrsim calibrate` prints."""
        value = f"{self.measured_kg_per_rev:.6g}"
        kg, error = self.settings.values()
        return "\n".join([
            f"Calibration of {self.scenario} ({self.form}): {self.revolutions} revolutions at "
            f"{self.test_shaft_rpm:.0f} rpm ({self.duration_s:.0f} s), the catch weighed on a scale "
            f"of +-{self.scale_error_g:g} g.",
            f"  Weighed {self.weighed_kg:.3f} kg: {value} kg/rev measured against "
            f"{self.configured_kg_per_rev:g} kg/rev configured ({self.change_pct:+.2f} %).",
            f"  Put in the scenario: [implement] kg_per_rev = {kg:.6g}; the same meter's true "
            f"{self.true_kg_per_rev:.6g} kg/rev then leaves [product] calibration_error_pct = {error:g}.",
            "  Or run with: " + " ".join(f"--set {k}={v:g}" for k, v in self.settings.items()),
        ])


def calibrate(scenario: Scenario, revolutions: int = DEFAULT_REVOLUTIONS,
              scale_error_g: float = DEFAULT_SCALE_ERROR_G) -> Calibration:
    """Simulate the calibration test of `scenario`'s meter for its product's form (`CALIBRATIONS`).

    Raises
    ------
    VrsimError
        `revolutions` or `scale_error_g` out of range, naming the option and its value.
    ScenarioError
        A product form with no calibration here (a liquid: the sprayer kind's), naming the file.
    """
    if isinstance(revolutions, bool) or not isinstance(revolutions, int) \
            or not 1 <= revolutions <= MAX_REVOLUTIONS:
        raise VrsimError(f"--revolutions {revolutions!r}: must be a whole number in [1, {MAX_REVOLUTIONS}]")
    if not in_range(scale_error_g, 0.0, MAX_SCALE_ERROR_G):
        raise VrsimError(f"--scale-error-g {scale_error_g!r}: must be a number of grams in "
                         f"[0, {MAX_SCALE_ERROR_G:g}]")
    form = scenario.product.form
    if form not in CALIBRATIONS:
        raise ScenarioError(f"{scenario_file(scenario)}: [product] form {form!r}: its calibration (a catch "
                            "or tank test) needs the sprayer machine kind; vrsim calibrate tests a granular "
                            "meter")
    return CALIBRATIONS[form](scenario, revolutions, scale_error_g)


def _granular(scenario: Scenario, revolutions: int, scale_error_g: float) -> Calibration:
    """A granular meter's test: `revolutions` whole turns into a bucket, weighed."""
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


# One calibration test per product form; the liquid form's (a sprayer's catch or tank volume test)
# comes with the sprayer machine kind.
CALIBRATIONS = {"granular": _granular}
