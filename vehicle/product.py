"""The product a machine meters: its form, its density, and how the meter's truth differs from its setting.

Two facts of real metering that a configured meter constant hides:

- **Calibration error.** The terminal computes the shaft speed from the configured ``kg_per_rev``; the
  product actually leaving the meter per revolution is ``kg_per_rev * (1 + calibration_error_pct /
  100)`` (a denser batch, a worn roller, a constant copied from the manual). A spreader-constant check
  by weighing exists to find it (`services.sim.calibrate`).
- **Flow variability.** The product metered per revolution is not the same every revolution (flutes
  fill unevenly, granules bridge). Modelled as a multiplicative factor drawn once per *shaft
  revolution* (correlation length one revolution: the unit a fluted roller repeats on), lognormal with
  mean 1 and coefficient of variation ``flow_cv_pct``, independent from revolution to revolution,
  seeded. Within a revolution the factor holds (the flute-to-flute pulsation inside one revolution is
  not modelled); a tick that spans parts of two revolutions gets each part's share. At 50 rpm a
  revolution lasts 1.2 s: the factor then varies second to second, as the metered flow does.

The factors are a function of the scenario's seed and the revolution's index alone, so any split of a
run into batches (the controller service's lockstep batches, a streamed run's parts) meters the same
product, given where the previous batch left the shaft (`metered_kg`'s ``start_rev``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim.common.checks import in_range
from vrsim.common.errors import VehicleError

PRODUCT_FORMS = ("granular", "liquid")
MAX_FLOW_CV_PCT = 50.0
CALIBRATION_ERROR_PCT = (-50.0, 100.0)   # open interval: below -50 % or 100 % over is not a calibration
MAX_DENSITY_KG_L = 25.0                   # denser than any metal: a typo
MAX_THOUSAND_SEED_MASS_G = 5000.0         # broad beans weigh up to ~2.5 kg per thousand: more is a typo
_FLOW_STREAM = 0x5EED_F10   # the flow factors' own random stream beside the seed's other uses


@dataclass(frozen=True)
class Product:
    """The product metered (``[product]`` in a scenario).

    Attributes
    ----------
    name : str
        What it is, for the reader.
    form : {"granular", "liquid"}
        A granular product is metered by a shaft (`vehicle.Implement`); a liquid one by a sprayer.
    density_kg_l : float or None
        Density (granular: bulk density), kg/L, > 0: converts volume and mass rates. None (the
        default): not given, and a map in a volume unit (L/ha, gal/ac) is refused rather than read
        with a guessed density.
    thousand_seed_mass_g : float or None
        Mass of a thousand seeds (TKW, thousand-kernel weight), g, in (0, 5000]: as seed labels and
        agronomists give it (wheat ~45 g, maize ~300 g). Converts a count rate map (seeds/ha,
        seeds/ac, the unit seeding prescriptions use) to kg/ha; None (the default): a count map is
        refused.
    flow_cv_pct : float
        Coefficient of variation of the product metered per shaft revolution, %, in [0, 50] (see the
        module docstring).
    calibration_error_pct : float
        The true meter constant against the configured one, %, in (-50, 100): true ``kg_per_rev`` =
        configured * (1 + error / 100).
    """

    name: str = "granular fertilizer"
    form: str = "granular"
    density_kg_l: float | None = None
    thousand_seed_mass_g: float | None = None
    flow_cv_pct: float = 0.0
    calibration_error_pct: float = 0.0

    def __post_init__(self):
        if self.form not in PRODUCT_FORMS:
            raise VehicleError(f"form must be one of {', '.join(PRODUCT_FORMS)}, got {self.form!r}")
        density = self.density_kg_l
        if density is not None and not in_range(density, 0.0, MAX_DENSITY_KG_L, lo_open=True):
            raise VehicleError(f"density_kg_l must be a number in (0, {MAX_DENSITY_KG_L:g}] kg/L, "
                               f"got {self.density_kg_l!r}")
        tkw = self.thousand_seed_mass_g
        if tkw is not None and not in_range(tkw, 0.0, MAX_THOUSAND_SEED_MASS_G, lo_open=True):
            raise VehicleError(f"thousand_seed_mass_g must be a number in (0, {MAX_THOUSAND_SEED_MASS_G:g}] "
                               f"g, got {tkw!r}")
        if not in_range(self.flow_cv_pct, 0.0, MAX_FLOW_CV_PCT):
            raise VehicleError(f"flow_cv_pct must be a number in [0, {MAX_FLOW_CV_PCT:g}] %, "
                               f"got {self.flow_cv_pct!r}")
        lo, hi = CALIBRATION_ERROR_PCT
        error = self.calibration_error_pct
        if not (in_range(error, lo, hi, lo_open=True) and error < hi):
            raise VehicleError(f"calibration_error_pct must be a number in ({lo:g}, {hi:g}) %, "
                               f"got {error!r}")

    @property
    def seed_mass_g(self) -> float | None:
        """The mass of one seed, g (`thousand_seed_mass_g` / 1000); None when not given."""
        return None if self.thousand_seed_mass_g is None else self.thousand_seed_mass_g / 1000.0

    def true_kg_per_rev(self, configured_kg_per_rev: float) -> float:
        """The product one shaft revolution really meters on average, kg/rev, for a configured one."""
        return configured_kg_per_rev * (1.0 + self.calibration_error_pct / 100.0)


def _flow_factors(product: Product, seed: int, count: int, stream: int = _FLOW_STREAM) -> np.ndarray:
    """The flow factors of shaft revolutions 0 .. `count` - 1: lognormal, mean 1, CV ``flow_cv_pct``.

    The first k factors are the same whatever `count` (a prefix of one seeded stream), so a batch
    that reaches further draws the same factors for the revolutions it shares with a shorter one.
    `stream` separates independent uses of the seed (the field's revolutions, a calibration test's).
    """
    if product.flow_cv_pct == 0:
        return np.ones(count)
    sigma2 = np.log1p((product.flow_cv_pct / 100.0) ** 2)
    normal = np.random.default_rng([seed, stream]).standard_normal(count)
    return np.exp(np.sqrt(sigma2) * normal - sigma2 / 2.0)


def metered_kg(forward_rev, kg_per_rev: float, product: Product, seed: int, start_rev=0.0,
               stream: int = _FLOW_STREAM) -> tuple[np.ndarray, np.ndarray | float]:
    """Product metered by `forward_rev` shaft revolutions per tick, and where the shaft then stands.

    Parameters
    ----------
    forward_rev : array_like, shape (ticks,) or (ticks, n)
        Forward shaft revolutions per tick (>= 0); n meters side by side in columns.
    kg_per_rev : float
        The configured meter constant, kg/rev (the true one is `Product.true_kg_per_rev`).
    product : Product
    seed : int
        The scenario's seed.
    start_rev : float or array_like of shape (n,)
        Revolutions the shaft turned before the first tick (each column's).
    stream : int
        The random stream (`_flow_factors`).

    Returns
    -------
    kg : ndarray, shape of `forward_rev`
        Product metered per tick, kg: revolutions x the true constant x each revolution's flow factor.
    end_rev : float or ndarray of shape (n,)
        Revolutions the shaft turned by the last tick: the next batch's `start_rev`.
    """
    rev = np.asarray(forward_rev, dtype=float)
    true_kg_per_rev = product.true_kg_per_rev(kg_per_rev)
    # The shaft's position after each tick, summed one tick after the other from `start_rev`: a batch
    # that starts where the previous one ended sums in the same order, so it gives the same numbers.
    first = np.broadcast_to(np.asarray(start_rev, dtype=float), (1, *rev.shape[1:]))
    position = np.cumsum(np.concatenate([first, rev]), axis=0)
    if product.flow_cv_pct == 0:
        return rev * true_kg_per_rev, position[-1]
    # The product up to shaft position p is the integral of the piecewise-constant factor:
    # cumulative[k] (whole revolutions before k) + factor[k] x the part of revolution k turned.
    factors = _flow_factors(product, seed, int(np.max(position)) + 1, stream)
    cumulative = np.concatenate([[0.0], np.cumsum(factors)])

    def integral(p):
        whole = np.floor(p).astype(int)
        return cumulative[whole] + factors[whole] * (p - whole)

    at = integral(position)   # once at each position: a tick's end is the next one's start
    return (at[1:] - at[:-1]) * true_kg_per_rev, position[-1]
