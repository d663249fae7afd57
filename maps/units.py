"""Application-rate units: what vrsim converts between, and how (one `pint` registry).

Mass per area (kg/ha, t/ha, lb/ac, g/m2), volume per area (L/ha, gal/ac (US), fl oz/ac, mL/m2) and
count per area (seeds/ha, seeds/ac); any other spelling pint reads as one of these kinds is accepted
too (``"kg ha-1"``, ``"lbs/ac"``, ``"l/ha"``, ``"gallon/acre"``) if it is of the short grammar
`_pint_text` checks before pint sees it (pint's parser evaluates numbers: ``9**9**9`` never returns).
Rates of different kinds convert only with the product's density (kg/L) or the mass of one seed (g),
which vrsim never guesses. vrsim computes in kg/ha; a map's own unit is used to read it and to show
its figures.
"""

from __future__ import annotations

import functools
import math
import re

import numpy as np

from common import MapError

KG_HA = "kg/ha"  # the unit vrsim computes in
# The spellings vrsim writes a unit in, first of each kind its base (what the run computes in).
RATE_UNITS = ("kg/ha", "t/ha", "lb/ac", "g/m2", "L/ha", "gal/ac", "floz/ac", "mL/m2", "seeds/ha", "seeds/ac")
_KINDS = {"[mass] / [length] ** 2": "mass", "[length]": "volume", "1 / [length] ** 2": "count"}
_BASE_UNITS = {"mass": "kg/ha", "volume": "L/ha", "count": "seeds/ha"}
_HINT = 'give it: [map] unit = "lb/ac" in the scenario, or --unit lb/ac (kg/ha, L/ha, gal/ac, seeds/ac ...)'
# A unit at the end of an attribute name: "Rate_lb_ac", "rate_kg_ha", "Rate (lb/ac)", "RATE[L/ha]".
_NAME_UNIT = re.compile(r"(?:^|[_ (\[])([A-Za-z]+)[_/]([A-Za-z0-9]+)[)\]]?$")

# pint's parser evaluates what it is given (``9**9**9`` never returns), so a unit reaches it only as
# rebuilt from this grammar: factors (a unit name, perhaps with an exponent of at most 2 digits, or a
# plain number) joined by ``/``, ``*``, ``.``, ``·`` or spaces. No parentheses, no exponent on a number.
MAX_UNIT_CHARS = 64
_LETTERS = "A-Za-z_%\u00b5\u03bc"  # and micro signs: "µL/m2"
_SUPER = "\u2070\u00b9\u00b2\u00b3\u2074-\u2079"  # superscript digits, a regex class: "m²"
_SUPERSCRIPTS = str.maketrans("\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b",
                              "0123456789-")
_FACTOR = re.compile(
    rf"(?P<name>[{_LETTERS}]+(?:\d+[{_LETTERS}]+)*)"  # digits inside a name only: "gal1ac", not "m2"
    rf"(?:(?:\^|\*\*)?(?P<exp>[-+]?\d{{1,2}})|(?P<sup>\u207b?[{_SUPER}]{{1,2}}))?(?![\d{_SUPER}])"
    rf"|(?P<number>\d{{1,6}}(?:\.\d{{1,6}})?)(?![\d^{_SUPER}]|\*\*)")  # "1/ha"; never raised to a power
_OPERATOR = re.compile(r"\s*([/*.\u00b7])\s*|\s+")  # between factors; spaces alone multiply
_GRAMMAR = ("a unit is names (kg, ha, lb, ac, ...) and numbers joined by /, *, . or spaces, each name "
            "with at most a 2-digit exponent (m2, ha-1, m^2)")


@functools.cache
def _registry():
    """The one pint registry, made on first use: pint takes about a second to load (it loads scipy), which
    a run in kg/ha, or a scenario parsed, never needs."""
    import pint

    units = pint.UnitRegistry(on_redefinition="ignore")  # "ignore": redefine without a warning
    # The international acre (the US acre since 2023, 4046.8564224 m^2; pint's is the survey acre,
    # 4 ppm larger), also spelled "ac" as farm files do (pint would read an abcoulomb).
    units.define("acre = 43560 * international_foot ** 2 = ac")
    units.define("seed = count = seeds")
    return units


def _pint_text(unit: str) -> str:
    """`unit` rebuilt for pint from the tokens of the grammar above (``"kg ha-1"`` -> ``"kg*ha**-1"``,
    ``"kg/m²"`` -> ``"kg/m**2"``); raises `ValueError` for anything else, before pint sees it."""
    text, at, out = unit.strip(), 0, []
    if len(unit) > MAX_UNIT_CHARS:
        raise ValueError(f"is not a unit vrsim reads (over {MAX_UNIT_CHARS} characters); {_GRAMMAR}")
    while True:
        factor = _FACTOR.match(text, at)
        if factor is None:
            raise ValueError(f"is not a unit vrsim reads (at character {at + 1}); {_GRAMMAR}")
        exp = factor["exp"] or (factor["sup"] or "").translate(_SUPERSCRIPTS)
        out.append(factor["number"] or factor["name"] + (f"**{exp}" if exp else ""))
        at = factor.end()
        if at == len(text):
            return "".join(out)
        operator = _OPERATOR.match(text, at)
        if operator is None:
            raise ValueError(f"is not a unit vrsim reads (at character {at + 1}); {_GRAMMAR}")
        out.append("/" if operator[1] == "/" else "*")
        at = operator.end()


def _shown_unit(unit) -> str:
    """`unit` quoted for an error message, shortened when long (a unit from a file can be anything)."""
    text = repr(unit)
    return text if len(text) <= 40 else f"{text[:30]}... ({len(unit):,} characters)"


@functools.lru_cache(maxsize=1024)  # bounded: the units read come from files and the bus
def _read(unit: str) -> tuple[str, str, float]:
    """(`unit` as vrsim writes it, its kind, its size in SI: kg/m^2, m^3/m^2 or 1/m^2); raises
    `ValueError` saying what it is otherwise."""
    text = _pint_text(unit)
    try:
        quantity = _registry().Quantity(1.0, text)
    # pint raises what it likes on odd names (KeyError for "m**0*%"): any failure to parse is no unit.
    except Exception as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"is not a unit pint reads ({first}); e.g. {', '.join(RATE_UNITS)}") from None
    kind = _KINDS.get(str(quantity.dimensionality))
    if kind is None:
        raise ValueError(f"is not a rate (mass, volume or count per area, e.g. kg/ha, L/ha, seeds/ac); it is "
                         f"{quantity.dimensionality}")
    si = float(quantity.to_base_units().magnitude)
    same = (name for name in RATE_UNITS if name != unit and _read(name)[1] == kind
            and math.isclose(_read(name)[2], si, rel_tol=1e-9))
    return (unit.strip() if unit in RATE_UNITS else next(same, unit.strip())), kind, si


def rate_unit(unit, where: str = "unit") -> str:
    """`unit` as vrsim writes it (``"lbs/ac"`` -> ``"lb/ac"``, ``"kg ha-1"`` -> ``"kg/ha"``).

    Raises
    ------
    MapError
        ``"{where}: ..."`` when pint cannot read `unit` or it is no mass, volume or count per area.
    """
    if not isinstance(unit, str) or not unit.strip():
        raise MapError(f"{where}: {_shown_unit(unit)} is not a rate unit; {_HINT}")
    if unit == KG_HA:  # vrsim's own unit: no need to load pint
        return KG_HA
    try:
        return _read(unit)[0]
    except ValueError as exc:
        raise MapError(f"{where}: {_shown_unit(unit)} {exc}") from None


def is_rate_unit(unit) -> bool:
    """True when `unit` is a rate unit `rate_unit` reads."""
    try:
        rate_unit(unit)
    except MapError:
        return False
    return True


def rate_kind(unit: str) -> str:
    """``"mass"``, ``"volume"`` or ``"count"`` (per area) of a unit `rate_unit` reads."""
    return "mass" if unit == KG_HA else _read(rate_unit(unit))[1]


def base_unit(unit: str) -> str:
    """kg/ha for a mass rate, L/ha for a volume rate, seeds/ha for a count."""
    return _BASE_UNITS[rate_kind(unit)]


# kg per unit of each kind's base: a volume (L) times kg/L, a count (seeds) times g per seed / 1000.
def _kg_per_base(kind: str, density_kg_l: float | None, seed_mass_g: float | None) -> float | None:
    if kind == "mass":
        return 1.0
    if kind == "volume":
        return density_kg_l
    return None if seed_mass_g is None else seed_mass_g / 1000.0


def convert_rate(values, unit: str, to_unit: str, density_kg_l: float | None = None,
                 seed_mass_g: float | None = None) -> np.ndarray:
    """Rates in `unit` expressed in `to_unit`.

    Parameters
    ----------
    values : array_like
        Rates in `unit`.
    unit, to_unit : str
        Rate units (`rate_unit`).
    density_kg_l : float, optional
        The product's density (kg/L), needed between a volume rate and a mass or count rate.
    seed_mass_g : float, optional
        The mass of one seed (g), needed between a count rate and a mass or volume rate.

    Raises
    ------
    MapError
        For a unit that is no rate, or a conversion between kinds without what it needs.
    """
    for name, value in (("density_kg_l", density_kg_l), ("seed_mass_g", seed_mass_g)):
        if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise MapError(f"{name} must be a number > 0, got {value!r}")
    unit, to_unit = rate_unit(unit), rate_unit(to_unit)
    if unit == to_unit:  # no pint for a map in kg/ha shown in kg/ha
        return np.asarray(values, dtype=np.float64) * 1.0
    (_, kind, si_from), (_, kind_to, si_to) = _read(unit), _read(to_unit)
    factor = si_from / si_to
    if kind != kind_to:
        per_from = _kg_per_base(kind, density_kg_l, seed_mass_g)
        per_to = _kg_per_base(kind_to, density_kg_l, seed_mass_g)
        if per_from is None or per_to is None:
            need = "density (kg/L)" if "volume" in (kind, kind_to) else "seed mass (g)"
            raise MapError(f"cannot convert a {kind} rate ({unit}) to a {kind_to} rate ({to_unit}) without "
                           f"the product's {need}")
        # SI of each kind (kg/m2, m3/m2, 1/m2) to its base (kg/ha, L/ha, seeds/ha), then through kg.
        base_from, base_to = (_read(_BASE_UNITS[k])[2] for k in (kind, kind_to))
        factor = si_from / base_from * per_from / per_to * base_to / si_to
    return np.asarray(values, dtype=np.float64) * factor


def map_unit(where: str, stated: str | None, given: str | None, key: str = "unit") -> str:
    """The unit of a map's rates: what the file states (`stated`, under `key`) or the user gives
    (`given`: ``[map] unit``, ``--unit``; it must agree with a unit the file states, and stands in
    for one pint cannot read); a map with neither is refused with `_HINT`."""
    if given is not None:
        unit = rate_unit(given, f"{where}: unit")
        if stated and is_rate_unit(stated) and rate_unit(stated) != unit:
            raise MapError(f"{where}: the file states its rates in {rate_unit(stated)} ({key}), not in the "
                           f"unit given, {given!r}")
        return unit
    if not stated:
        raise MapError(f"{where}: the map does not state the unit of its rates; {_HINT}")
    return rate_unit(stated, f"{where}: {key}")


def name_with_unit(unit: str) -> str:
    """The rate attribute's name that states `unit` (`unit_in_name` reads it back): ``rate_kg_ha``."""
    return f"rate_{unit.replace('/', '_')}"


def unit_in_name(name: str) -> str | None:
    """The rate unit an attribute name ends with (``"Rate_lb_ac"``, ``"Rate (lb/ac)"``,
    ``"rate_kg_ha"``, ``"RATE_LB_AC"``: DBF names are often upper case), or None when it names none."""
    match = _NAME_UNIT.search(name.strip())
    if match is None:
        return None
    unit = f"{match.group(1)}/{match.group(2)}"
    return next((rate_unit(u) for u in (unit, unit.lower()) if is_rate_unit(u)), None)
