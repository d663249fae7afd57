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

from vrsim.common import MapError

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
    units.define("gpm = gallon / minute")  # US gallons a minute: a nozzle's or a boom's flow
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


class MapUnitError(MapError):
    """A map whose rates' unit is neither stated nor given, or stated in words pint cannot read:
    `problem` says which, without the file's name (`vrsim map info` describes such a map anyway)."""

    def __init__(self, message: str, problem: str):
        super().__init__(message)
        self.problem = problem


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
        raise MapUnitError(f"{where}: the map does not state the unit of its rates; {_HINT}",
                           "not stated in the file")
    try:
        return rate_unit(stated, f"{where}: {key}")
    except MapError as exc:
        raise MapUnitError(str(exc), str(exc).removeprefix(f"{where}: ")) from None


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


# --- Units a figure is shown in, and units given with a scenario's values ---------------------------
# vrsim computes and writes its files and JSON keys in SI (and kg/ha, L/min, bar: units in the names);
# what it prints, draws and reports is in the user's system of units: "metric" as computed, or "us",
# each unit of `US_UNITS` shown as its US customary unit. A map in a US unit (lb/ac, gal/ac, floz/ac,
# seeds/ac) makes "us" the default (`unit_system`).
UNIT_SYSTEMS = ("metric", "us")
# The one table of display units: a unit vrsim shows a figure in -> the US customary unit shown for it
# (the US gallon, international foot, acre and mile). In "metric" a US unit (a map's lb/ac) is shown as
# the first unit here that maps to it.
US_UNITS = {
    "kg": "lb", "g": "oz", "ha": "ac", "m": "ft", "km": "mi", "m/s": "mph", "km/h": "mph",
    "L": "gal", "mL": "floz", "L/min": "gpm", "bar": "psi", "kPa": "psi",
    "kg/ha": "lb/ac", "t/ha": "lb/ac", "g/m2": "lb/ac", "L/ha": "gal/ac", "mL/m2": "gal/ac",
    "mL/ha": "floz/ac", "seeds/ha": "seeds/ac", "kg/L": "lb/gal",
}
# Scenario keys that hold a length, a speed or a pressure, by the unit their name ends in: such a key
# (``width_m``), or the same name without it (``width``), also takes a number with a unit as a string
# ("120 ft", "10 mph", "15 psi"), which `quantity_in` reads into the key's unit. Longest suffix first.
KEY_UNITS = (("_m_s", "m/s", "speed"), ("_kpa", "kPa", "pressure"), ("_bar", "bar", "pressure"),
             ("_pa", "Pa", "pressure"), ("_m", "m", "length"))
_QUANTITY = re.compile(r"\s*(?P<number>[-+]?(?:\d{1,15}(?:\.\d{0,15})?|\.\d{1,15})(?:[eE][-+]?\d{1,3})?)"
                       r"\s*(?P<unit>.*?)\s*$")
_KIND_EXAMPLES = {"length": "ft, in, yd, m", "speed": "mph, km/h, ft/s, m/s", "pressure": "psi, bar, kPa"}


def unit_system(map_unit: str | None, units: str | None = None) -> str:
    """The system of units figures are shown in: `units` when given ("metric" or "us", ``[output]
    units``), else "us" for a map whose rates are in a US unit (lb/ac, gal/ac, floz/ac, seeds/ac),
    "metric" otherwise."""
    if units is not None:
        return units
    return "us" if map_unit is not None and map_unit in US_UNITS.values() else "metric"


def _display_unit(unit: str, system: str) -> str:
    """The unit a figure in `unit` is shown in under `system` (`US_UNITS`); `unit` when the table has
    none for it (%, s, rpm, a count)."""
    if system == "us":
        return US_UNITS.get(unit, unit)
    return next((metric for metric, us in US_UNITS.items() if us == unit), unit)


@functools.cache  # bounded: units of `US_UNITS` only
def _factor(unit: str, to_unit: str) -> float:
    return float(_registry().Quantity(1.0, _pint_text(unit)).to(_pint_text(to_unit)).magnitude)


def in_units(value, unit: str, system: str):
    """`value` (a figure in `unit`) as shown under `system`: ``(value, unit)`` converted by pint to
    `_display_unit`. A number, a list or an array of numbers converts (NaN stays NaN); anything else
    (None, a bool, a string) is returned as it is.

    >>> in_units(36.576, "m", "us")
    (120.0..., 'ft')
    """
    shown = _display_unit(unit, system)
    if shown == unit or value is None or isinstance(value, (bool, str)):
        return value, unit
    factor = _factor(unit, shown)
    if isinstance(value, (list, tuple)):
        return [None if v is None else float(v) * factor for v in value], shown
    if isinstance(value, np.ndarray):
        return value * factor, shown
    return float(value) * factor, shown


def key_unit(key: str) -> tuple[str, str] | None:
    """(unit, kind) of a scenario key whose name ends in a length, speed or pressure unit
    (`KEY_UNITS`: ``"width_m"`` -> ``("m", "length")``), None for any other key."""
    return next(((unit, kind) for suffix, unit, kind in KEY_UNITS if key.endswith(suffix)), None)


def quantity_in(text, unit: str, kind: str) -> float:
    """A number with a unit (``"120 ft"``, ``"10 mph"``, ``"15 psi"``) in `unit` (m, m/s, bar), to 12
    significant digits (``"120 ft"`` is 36.576 m, as typed in metres, not 36.575999999999993).

    The unit is read with the grammar of rate units (`_pint_text`: pint never sees anything else) and
    must be of `kind` ("length", "speed" or "pressure").

    Raises
    ------
    ValueError
        Saying what is wrong (no number, no unit, a unit pint does not read or of another kind); the
        caller names the key and the value.
    """
    if not isinstance(text, str) or len(text) > 2 * MAX_UNIT_CHARS:
        raise ValueError(f"is not a {kind} with a unit (e.g. {_KIND_EXAMPLES[kind]})")
    match = _QUANTITY.fullmatch(text)
    if match is None or not match["unit"]:
        raise ValueError(f"is not a number with a unit of {kind} (e.g. {_KIND_EXAMPLES[kind]})")
    number, text = float(match["number"]), _pint_text(match["unit"])  # the grammar's ValueError
    try:
        quantity = _registry().Quantity(1.0, text)
    # pint raises what it likes on odd names (KeyError for "m**0*%"): any failure to parse is no unit.
    except Exception as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"has a unit pint does not read ({first}); e.g. {_KIND_EXAMPLES[kind]}") from None
    target = _registry().Quantity(1.0, _pint_text(unit))
    if quantity.dimensionality != target.dimensionality:
        raise ValueError(f"is not a {kind} (its unit is {quantity.dimensionality}); e.g. "
                         f"{_KIND_EXAMPLES[kind]}")
    si = quantity.to(target.units).magnitude
    value = number * float(si)
    if not math.isfinite(value):
        raise ValueError(f"is not a finite {kind}")
    return float(f"{value:.12g}")


def shown_text(value: float, unit: str, system: str, spec: str = ".2f") -> str:
    """``"12.75 mph"``: `value` in `unit` as shown under `system` (`in_units`), formatted by `spec`."""
    shown, to_unit = in_units(value, unit, system)
    return f"{shown:{spec}} {to_unit}"


def shown_range(low: float, high: float, unit: str, system: str, spec: str = ".2f",
                between: str = "-") -> str:
    """``"5.3-5.9 mph"``: a range in `unit` as shown under `system`, its unit once."""
    (lo, to_unit), (hi, _) = in_units(low, unit, system), in_units(high, unit, system)
    return f"{lo:{spec}}{between}{hi:{spec}} {to_unit}"
