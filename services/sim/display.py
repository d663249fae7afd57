"""A run's figures in the user's units: the system a run shows its figures in, and each figure as shown.

vrsim computes in SI (and kg/ha, L/min, bar: units in the names) and its JSON keys stay so; what it
prints, reports and draws is in ``[output] units`` ("metric" or "us"; unset: "us" for a map in lb/ac
or gal/ac, `maps.units.unit_system`), each unit converted by `maps.units.in_units` (the one table,
`maps.units.US_UNITS`). A rate figure is first in the map's own unit (the summary's ``in_rate_unit``),
then in that unit's counterpart if the map's unit is of the other system (gal/ac shown as L/ha in
"metric").
"""

from __future__ import annotations

from vrsim.maps.units import in_units, rate_kind, rate_unit, unit_system
from vrsim.services.sim import metrics
from vrsim.services.sim.metrics import METRICS, RATE_UNIT, rate_key


def run_units(world) -> str:
    """The system of units the run of `world` (`services.sim.world.World`) shows its figures in:
    ``[output] units``, else from its map's rate unit."""
    return unit_system(world.grid.map_unit, world.scenario.output.units)


def run_summary(accounts) -> dict:
    """A run's summary (`services.sim.metrics.summary` of its `Accounts`), for a liquid's map
    ``in_product_unit`` (`_in_product_unit`), and ``units``, the system its figures are shown in
    (`run_units`; the figures stay SI): what `services.sim.run.RunResult` and the batched variants
    (`services.sim.variants`) hold."""
    summary, grid = metrics.summary(accounts), accounts.setting.world.grid
    litres = _in_product_unit(summary, grid.map_unit, grid.density_kg_l)
    return {**summary, **({"in_product_unit": litres} if litres else {}),
            "units": run_units(accounts.setting.world)}


def _in_product_unit(summary: dict, map_unit: str, density_kg_l: float | None) -> dict:
    """The product figures (the `METRICS` rows in kg) in litres, ``{"applied_kg": ...}``, for a map in
    a volume rate (L/ha, gal/ac) read with the product's density: a liquid is shown by its volume, as
    its rates are; empty for any other map."""
    if density_kg_l is None or rate_kind(map_unit) != "volume":
        return {}
    return {m.key: summary[m.key] / density_kg_l for m in METRICS if m.unit == "kg"}


def scenario_units(scenario) -> str:
    """`run_units` of a scenario whose world is not built (`vrsim calibrate`): ``[output] units``, else
    from ``[map] unit`` or the unit the map file states (a synthetic map is in kg/ha)."""
    spec = scenario.map
    if scenario.output.units is not None or spec.file is None:
        return unit_system(None, scenario.output.units)
    if spec.unit is not None:
        return unit_system(rate_unit(spec.unit))
    from vrsim.maps import read_map

    grid = read_map(scenario.path(spec.file), rate_field=spec.rate_field, cell_size_m=spec.cell_size_m,
                    crs=spec.crs, density_kg_l=scenario.product.density_kg_l)
    return unit_system(grid.map_unit)


def shown_figure(summary: dict, key: str, unit: str) -> tuple:
    """(value, unit) of figure `key` (its `METRICS` `unit`) of a run's `summary` as shown in the
    summary's ``units`` (without: the system of its ``rate_unit``): a rate figure in the map's unit
    (``in_rate_unit``) first, a liquid's product in litres (``in_product_unit``)."""
    value = summary[key]
    own = summary.get("in_rate_unit", {})
    if unit == RATE_UNIT and rate_key(key) in own:
        value, unit = own[rate_key(key)], summary.get("rate_unit", RATE_UNIT)
    elif unit == "kg" and key in summary.get("in_product_unit", {}):   # a liquid, by its volume
        value, unit = summary["in_product_unit"][key], "L"
    return in_units(value, unit, summary.get("units") or unit_system(summary.get("rate_unit")))


def displayed(summary: dict) -> dict:
    """``{key: {"value": ..., "unit": ...}}``: every `METRICS` figure of `summary` as shown
    (`shown_figure`), what ``vrsim run --json`` and summary.json hold under ``display``."""
    out = {}
    for m in METRICS:
        if m.key in summary:
            value, unit = shown_figure(summary, m.key, m.unit)
            out[m.key] = {"value": value, "unit": unit}
    return out


# The unit of a figure by the end of its key (a machine check's, a calibration's); "_per_" keys are
# settings in units of their own (kg_per_rev, pulses_per_l), shown as they are.
_KEY_UNITS = (("_m_s", "m/s"), ("_l_min", "L/min"), ("_kg_ha", RATE_UNIT), ("_kg", "kg"), ("_ml", "mL"),
              ("_l", "L"), ("_g", "g"), ("_bar", "bar"), ("_m", "m"))
_RPM_KEYS = ("rpm_min", "rpm_max", "shaft_rpm_min", "shaft_rpm_max")


def figures_display(figures: dict, units: str) -> dict:
    """``{key: {"value": ..., "unit": ...}}``: the numbers of `figures` whose key ends in a unit
    (``caught_kg``, ``read_l``, ``speed_max_m_s``) as shown in `units`; what ``--json`` adds under
    ``display``."""
    out = {}
    for key, value in figures.items():
        unit = None if "_per_" in key else next((u for suffix, u in _KEY_UNITS if key.endswith(suffix)), None)
        if unit is not None and isinstance(value, (int, float)) and not isinstance(value, bool):
            shown, shown_unit = in_units(value, unit, units)
            out[key] = {"value": shown, "unit": shown_unit}
    return out


def check_display(check, grid, units: str) -> dict:
    """``{key: {"value": ..., "unit": ...}}``: the figures of a machine check
    (`services.sim.limits.MachineCheck`) with a unit as shown in `units` (``vrsim run --check --json``'s
    ``display``): speeds, lengths, flows, and its rates in the unit of `grid` (`maps.Grid`) first."""
    out = figures_display({k: v for k, v in vars(check).items() if not k.endswith("_kg_ha")}, units)
    for key, value in check.in_rate_unit(grid).items():  # the rates, in the map's unit first
        shown, shown_unit = in_units(value, grid.map_unit, units)
        out[f"{key}_kg_ha"] = {"value": shown, "unit": shown_unit}
    for key in _RPM_KEYS:
        shown, shown_unit = in_units(getattr(check, key), check.RPM_UNIT, units)
        out[key] = {"value": shown, "unit": shown_unit}
    return out
