"""Scenario files: one TOML file says which field, map, machine, GNSS and controller to run.

Every table maps onto one configuration dataclass of the package that owns the concept
(``[implement]`` -> `vehicle.Implement`, ``[tractor]`` -> `vehicle.DriveConfig`, ``[gnss]`` ->
`vehicle.GnssConfig`, ``[controller]`` -> `controller.ControllerConfig`, ``[plant]`` ->
`controller.PlantParams`, ``[product]`` -> `vehicle.product.Product`, ``[response]`` ->
`vehicle.response.MachineResponse`), so a key is named and
documented once, where it is used. Loading checks every key: unknown keys, wrong types and values
the owning dataclass refuses all raise a `ScenarioError` that names the file, the table and key, and
the value.

See ``scenarios/README.md`` for the keys of each table and ``services/sim/scenarios/default.toml`` for
the built-in default.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field

from vrsim.common import MapError, ScenarioError, files, is_number
from vrsim.common.toml_text import loads_toml
from vrsim.controller import ControllerConfig, PlantParams
from vrsim.controller.config import PID_KINDS
from vrsim.maps import synthetic
from vrsim.maps.units import UNIT_SYSTEMS, rate_unit
from vrsim.services.sim.machines.keys import changed_implement, implement_from_table
from vrsim.services.sim.overrides import Override
from vrsim.services.sim.overrides import apply as apply_overrides
from vrsim.services.sim.tables import build, no_unknown, typed, with_units
from vrsim.vehicle import DriveConfig, GnssConfig, Implement, SpeedSensorConfig
from vrsim.vehicle.driver import MAX_SEED, STEP_RANGE_S
from vrsim.vehicle.field import SLIVER_M2
from vrsim.vehicle.product import Product
from vrsim.vehicle.response import MachineResponse

BUILTIN_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "scenarios")
SYNTHETIC_KINDS = ("uniform", "zones", "gradient", "random_field", "checkerboard", "zones_gradient")
POLICIES = ("off", "hold", "default")
MAX_SIM_TIME_S = 1e6  # an explicit time limit above ~11.6 days of driving is a typo, not a field


@dataclass(frozen=True)
class FieldSpec:
    """Where the field is: exactly one of `file`, `rectangle`, `polygon_lonlat` or `from_map`."""

    file: str | None = None
    crs: str | None = None  # for a shapefile without .prj
    rectangle: dict | None = None  # {width_m, length_m, lat, lon}
    polygon_lonlat: list | None = None  # [[lon, lat], ...]
    from_map: bool = False  # the union of the [map] file's zones (`vehicle.Field.from_polygons`)
    union: bool = False  # a `file` of several polygons: their union (else refused)
    sliver_m2: float = SLIVER_M2  # a union's parts and holes under this area are dropped
    headland_passes: int = 1
    heading_deg: float | None = None  # AB heading; None = along the longest edge
    turn_radius_m: float = 6.0

    def __post_init__(self):
        if isinstance(self.rectangle, dict):  # its sides may be given with a unit: width = "400 ft"
            object.__setattr__(self, "rectangle", with_units(self.rectangle, ("width_m", "length_m"),
                                                             "rectangle", ""))


@dataclass(frozen=True)
class MapSpec:
    """The prescription: a file `maps.read_map` reads, or a synthetic map of kind `synthetic`."""

    file: str | None = None
    rate_field: str | None = None
    crs: str | None = None
    synthetic: str | None = None
    cell_size_m: float = 2.0
    params: dict = field(default_factory=dict)  # keyword arguments of the synthetic generator
    policy: str = "off"  # what the controller does outside the map or on nodata
    default_rate_kg_ha: float = 0.0
    unit: str | None = None  # the file's rate unit, when it does not state it (`maps.units.rate_unit`)


@dataclass(frozen=True)
class TimingSpec:
    control_period_s: float = 0.05
    plant_step_s: float = 0.001
    # Simulated time after which an unfinished drive fails (a stalled tractor). None: derived from
    # the path by `vehicle.SumoDriver` (10 x the path at the slowest speed, plus 60 s), so a field of
    # any size runs without raising it.
    max_sim_time_s: float | None = None
    # SUMO's step, a whole multiple of the control period (the ticks between its steps interpolated
    # along the path: docs/model.md, "SUMO's step"). None: the control period.
    sumo_step_s: float | None = None


POINT_FORMATS = ("gpkg", "shp", "none")
TRACK_FORMATS = ("parquet", "csv")   # ``[output] track``: the per-tick track's files, or "none"


@dataclass(frozen=True)
class OutputSpec:
    """What a run writes beside summary.json, the GeoTIFFs and the TASKDATA.

    Attributes
    ----------
    plots, html : bool
        map.png and timeseries.png; report.html.
    log_rate_hz : float
        Records per second of the as-applied log (taskdata/ and the points file); 1 Hz, as terminals
        log. At most the control rate (1 / control_period_s).
    points : {"gpkg", "shp", "none"}
        The as-applied points file: as_applied_points.gpkg, as_applied_points.zip (a zipped
        shapefile), or none.
    track : str or list of str
        The per-tick track: "parquet" (track.parquet, columnar: a big field's track in a fraction of
        the CSV's size and time), "csv" (track.csv), a list of both, or "none" (`track_formats`).
    units : {"metric", "us"} or None
        The units every printed, reported and drawn figure is shown in (`maps.units.US_UNITS`; files
        and JSON keys stay SI); None: "us" for a map in a US unit (lb/ac, gal/ac), else "metric"
        (`maps.units.unit_system`).
    """

    plots: bool = True
    html: bool = True
    log_rate_hz: float = 1.0
    points: str = "gpkg"
    track: str | list | tuple = ("parquet",)
    units: str | None = None

    def __post_init__(self):
        if isinstance(self.track, list):   # a TOML array: the same value as the default's tuple
            object.__setattr__(self, "track", tuple(self.track))

    @property
    def track_formats(self) -> tuple[str, ...]:
        """The track's file formats asked for, in `TRACK_FORMATS`' order (none: empty)."""
        asked = {self.track} if isinstance(self.track, str) else set(self.track)
        return tuple(f for f in TRACK_FORMATS if f in asked)


@dataclass(frozen=True)
class Scenario:
    name: str
    source: str  # the file it came from, or "builtin:<name>"
    base_dir: str  # relative paths in the file are relative to this
    seed: int
    description: str
    field: FieldSpec
    map: MapSpec
    implement: Implement
    tractor: DriveConfig
    gnss: GnssConfig
    speed_sensor: SpeedSensorConfig
    controller: ControllerConfig
    plant: PlantParams
    timing: TimingSpec
    output: OutputSpec
    product: Product = field(default_factory=Product)   # what the machine meters (its truth, too)
    response: MachineResponse = field(default_factory=MachineResponse)   # beyond the plant: a log's fit

    def path(self, relative: str) -> str:
        """A path from the scenario file, resolved against the file's folder."""
        return relative if os.path.isabs(relative) else os.path.join(self.base_dir, relative)


# The tables of a scenario file (in the order `to_toml` writes them) and all its top-level keys.
TABLES = ("field", "map", "implement", "tractor", "gnss", "speed_sensor", "controller", "plant", "timing",
          "output", "product", "response")
TOP_KEYS = {"name", "seed", "description", *TABLES}


def builtin_names() -> list[str]:
    return sorted(f[:-5] for f in os.listdir(BUILTIN_DIR) if f.endswith(".toml"))


def scenario_file(scenario: Scenario) -> str:
    """The file a loaded scenario was read from (a built-in's TOML under `BUILTIN_DIR`)."""
    if scenario.source.startswith("builtin:"):
        return os.path.join(BUILTIN_DIR, scenario.source[len("builtin:"):] + ".toml")
    return scenario.source


def load(spec: str | None, overrides: Iterable[Override] = ()) -> Scenario:
    """Load a scenario from a file path or a built-in name (None = the built-in default), with
    dotted-key `overrides` (``("controller.kp", 0.8)``) applied before it is checked."""
    return parse(*read(spec), overrides=overrides)


def read(spec: str | None) -> tuple[str, str, str]:
    """(text, source, base_dir) of a scenario file path or built-in name (None = the default)."""
    if spec is None:
        spec = "default"
    if not os.path.exists(spec) and spec in builtin_names():
        with open(os.path.join(BUILTIN_DIR, spec + ".toml"), "rb") as fh:
            return fh.read().decode(), f"builtin:{spec}", BUILTIN_DIR
    if not os.path.exists(spec):
        raise ScenarioError(f"{spec}: no such scenario file (built-in scenarios: "
                            f"{', '.join(builtin_names())})")
    data = files.read_bytes(spec, "toml", ScenarioError)  # a regular file within the TOML cap
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{spec}: cannot read: {exc}") from None
    return text, spec, os.path.dirname(os.path.abspath(spec))


def parse(text: str, source: str = "<scenario>", base_dir: str = ".",
          overrides: Iterable[Override] = ()) -> Scenario:
    """Parse and check a scenario's TOML text; `source` names it in error messages. `overrides`
    (dotted key, value) are set in the document first (`services.sim.overrides`), so they are
    checked like the file's own keys."""
    cap = files.cap_for("toml")
    if len(text) > cap:
        raise ScenarioError(f"{source}: {len(text):,} characters is over the {cap:,}-byte cap for "
                            "scenario files")
    try:
        return _parse(text, source, base_dir, overrides)
    except RecursionError:  # arrays or tables nested thousands deep
        raise ScenarioError(f"{source}: not a scenario: values nested too deeply") from None


def _parse(text: str, source: str, base_dir: str, overrides: Iterable[Override]) -> Scenario:
    try:
        doc = loads_toml(text, f"{source}: not a scenario", ScenarioError)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from None
    doc = apply_overrides(doc, overrides, source)
    no_unknown(doc, TOP_KEYS, source, "")
    for key in TABLES:
        if key in doc and not isinstance(doc[key], dict):
            raise ScenarioError(f"{source}: [{key}] must be a table, got {doc[key]!r}")
    name = typed(doc, "name", str, source, "", default=os.path.splitext(os.path.basename(source))[0])
    seed = typed(doc, "seed", int, source, "", default=1)
    scenario = Scenario(
        name=name.replace("builtin:", ""),
        source=source,
        base_dir=base_dir,
        seed=seed,
        description=typed(doc, "description", str, source, "", default=""),
        field=build(FieldSpec, doc.get("field", {}), source, "field"),
        map=build(MapSpec, doc.get("map", {}), source, "map"),
        implement=implement_from_table(doc.get("implement", {}), source, base_dir),
        tractor=build(DriveConfig, doc.get("tractor", {}), source, "tractor"),
        gnss=build(GnssConfig, doc.get("gnss", {}), source, "gnss"),
        speed_sensor=build(SpeedSensorConfig, doc.get("speed_sensor", {}), source, "speed_sensor"),
        controller=controller_from_table(doc.get("controller", {}), source, base_dir),
        plant=build(PlantParams, doc.get("plant", {}), source, "plant"),
        timing=build(TimingSpec, doc.get("timing", {}), source, "timing"),
        output=build(OutputSpec, doc.get("output", {}), source, "output"),
        product=build(Product, doc.get("product", {}), source, "product"),
        response=build(MachineResponse, doc.get("response", {}), source, "response"),
    )
    _machine_once(doc.get("plant", {}), source)
    _check(scenario)
    return scenario


def with_changes(scenario: Scenario, **changes) -> Scenario:
    """A copy of `scenario` with some values changed, checked as a scenario file's would be.

    Parameters
    ----------
    scenario : Scenario
    **changes
        ``name``, ``seed`` or ``description``, or a table as a dict of the keys to change, e.g.
        ``implement={"width_m": 18.0}``, ``controller={"kind": "PI"}``; the other keys keep their values.

    Returns
    -------
    Scenario
        The changed copy (the original is frozen and stays as it was).

    Raises
    ------
    ScenarioError
        Naming the scenario, the table, the key and the value, as loading a file with it would.

    ``dataclasses.replace`` works too (``replace(sc, implement=replace(sc.implement, width_m=18.0))``):
    the owning dataclass checks its own values, but not what a scenario checks across tables.
    """
    source, top = scenario.source, {}
    for key, value in changes.items():
        if key in ("name", "description"):
            top[key] = typed(changes, key, str, source, "")
        elif key == "seed":
            top[key] = typed(changes, key, int, source, "")
        elif key in TOP_KEYS:
            if not isinstance(value, dict):
                raise ScenarioError(f"{source}: [{key}] changes must be a dict of its keys, got {value!r}")
            current = getattr(scenario, key)
            kept = {f.name: getattr(current, f.name) for f in dataclasses.fields(current) if f.init}
            if key == "controller":
                top[key] = _changed_controller(current, kept, value, scenario)
                continue
            if key == "implement":
                top[key] = changed_implement(current, value, source, scenario.base_dir)
                continue
            no_unknown(value, kept, source, key)
            if key == "plant":
                _machine_once(value, source)
            top[key] = build(type(current), {**kept, **value}, source, key)
        else:
            no_unknown({key: value}, TOP_KEYS, source, "")
    changed = dataclasses.replace(scenario, **top)
    _check(changed)
    return changed


CONTROLLER_KEYS = {f.name for f in dataclasses.fields(ControllerConfig)} - {"class_name"} | {"class"}
# What a controller's configuration keeps when its kind changes: the rest belongs to the old kind.
KIND_INDEPENDENT_KEYS = ("look_ahead_s", "look_ahead_tune")


def controller_from_table(table: dict, source: str, base_dir: str) -> ControllerConfig:
    """A ``[controller]`` table -> `ControllerConfig` (a `ScenarioError` naming `source`, the key and
    the value if it is bad): the TOML key ``class`` is its `class_name` (a Python
    keyword cannot be a field); ``file`` (kind "python") is taken relative to the scenario's folder
    and must exist (its class is loaded when a run builds the loop, not here: parsing never runs
    user code)."""
    no_unknown(table, CONTROLLER_KEYS, source, "controller")
    renamed = {("class_name" if k == "class" else k): v for k, v in table.items()}
    cfg = build(ControllerConfig, renamed, source, "controller").resolved(base_dir)
    if cfg.file is not None and not os.path.isfile(cfg.file):
        raise ScenarioError(f"{source}: [controller] file {table.get('file', cfg.file)!r}: no such file "
                            f"({cfg.file})")
    return cfg


def _changed_controller(current: ControllerConfig, kept: dict, changes: dict, scenario: Scenario):
    """`with_changes` of ``[controller]``: keys as in a file (``class``); a change of kind starts from
    that kind's defaults and keeps only the look-ahead (`KIND_INDEPENDENT_KEYS`)."""
    no_unknown(changes, CONTROLLER_KEYS, scenario.source, "controller")
    new_kind = changes.get("kind", current.kind)
    if new_kind != current.kind and not (isinstance(new_kind, str) and _same_family(new_kind, current.kind)):
        kept = {k: kept[k] for k in KIND_INDEPENDENT_KEYS}
    merged = {**kept, **changes}
    table = {("class" if k == "class_name" else k): v for k, v in merged.items() if v is not None}
    return controller_from_table(table, scenario.source, scenario.base_dir)


def _same_family(kind: str, other: str) -> bool:
    """P, PI, PID (and "pid") share their keys: a change among them keeps gains and form."""
    return kind in PID_KINDS and other in PID_KINDS


def _machine_once(plant_table: dict, source: str) -> None:
    for key in ("transmission_ratio", "shaft_rpm_max"):
        if key in plant_table:
            raise ScenarioError(f"{source}: [plant] {key}: set it in [implement], which describes the "
                                f"machine once (got {plant_table[key]!r})")


def _check(scenario: Scenario) -> None:
    """What a scenario checks across its tables (each table's dataclass checks its own values)."""
    source = scenario.source
    if not 0 <= scenario.seed <= MAX_SEED:
        raise ScenarioError(f"{source}: seed must be in [0, {MAX_SEED}], got {scenario.seed}")
    _check_field(scenario.field, source)
    _check_map(scenario.map, source, scenario.field)
    _check_timing(scenario.timing, source)
    _check_output(scenario.output, scenario.timing, source)


def _check_field(spec: FieldSpec, source: str) -> None:
    given = [k for k in ("file", "rectangle", "polygon_lonlat") if getattr(spec, k) is not None]
    given += ["from_map"] if spec.from_map else []
    if len(given) != 1:
        raise ScenarioError(f"{source}: [field] needs exactly one of file, rectangle, polygon_lonlat, "
                            f"from_map = true (got {', '.join(given) or 'none'})")
    if spec.union and spec.file is None:
        raise ScenarioError(f"{source}: [field] union = true is for a file of several polygons; there is "
                            "no [field] file")
    if not (is_number(spec.sliver_m2) and spec.sliver_m2 >= 0):
        raise ScenarioError(f"{source}: [field] sliver_m2 must be a number >= 0 (m^2), got "
                            f"{spec.sliver_m2!r}")
    if spec.rectangle is not None:
        no_unknown(spec.rectangle, {"width_m", "length_m", "lat", "lon"}, source, "field.rectangle")
        for key in ("width_m", "length_m", "lat", "lon"):
            value = spec.rectangle.get(key)
            if not is_number(value):
                raise ScenarioError(f"{source}: [field.rectangle] {key} must be a number, got {value!r}")
    if spec.headland_passes < 0:
        raise ScenarioError(f"{source}: [field] headland_passes must be >= 0, got {spec.headland_passes}")
    if spec.turn_radius_m <= 0:
        raise ScenarioError(f"{source}: [field] turn_radius_m must be > 0, got {spec.turn_radius_m}")


def _check_map(spec: MapSpec, source: str, field_spec: FieldSpec | None = None) -> None:
    if (spec.file is None) == (spec.synthetic is None):
        raise ScenarioError(f"{source}: [map] needs exactly one of file or synthetic")
    if field_spec is not None and field_spec.from_map and spec.file is None:
        raise ScenarioError(f"{source}: [field] from_map = true takes the field from the [map] file's "
                            f"zones; [map] is synthetic {spec.synthetic!r}: give [map] file")
    if spec.synthetic is not None:
        if spec.synthetic not in SYNTHETIC_KINDS:
            raise ScenarioError(f"{source}: [map] synthetic must be one of {', '.join(SYNTHETIC_KINDS)}, "
                                f"got {spec.synthetic!r}")
        no_unknown(spec.params, _synthetic_params(spec.synthetic), source, "map.params")
    if spec.policy not in POLICIES:
        raise ScenarioError(f"{source}: [map] policy must be one of {', '.join(POLICIES)}, "
                            f"got {spec.policy!r}")
    if not spec.cell_size_m > 0:
        raise ScenarioError(f"{source}: [map] cell_size_m must be > 0, got {spec.cell_size_m}")
    if spec.default_rate_kg_ha < 0:
        raise ScenarioError(f"{source}: [map] default_rate_kg_ha must be >= 0, got {spec.default_rate_kg_ha}")
    if spec.unit is not None:
        try:  # first: a unit pint never sees unless it is short and of the grammar `rate_unit` reads
            rate_unit(spec.unit, f"{source}: [map] unit")
        except MapError as exc:
            raise ScenarioError(str(exc)) from None
        if spec.file is None:
            raise ScenarioError(f"{source}: [map] unit {spec.unit!r} is for a map file; synthetic maps "
                                "are in kg/ha")


def product_density_kg_l(scenario: Scenario) -> float | None:
    """The product's density, kg/L (``[product] density_kg_l``), which converts a volume rate map to
    kg/ha; None when the scenario gives none."""
    return scenario.product.density_kg_l


def _synthetic_params(kind: str) -> set[str]:
    """The `[map] params` keys a synthetic map of `kind` takes (`zones_gradient`: the zones' keys and
    the gradient's prefixed with ``gradient_``)."""
    def own(name):
        given = {"bounds", "crs", "cell_size_m", "seed"}  # set by the run, not by the file
        return set(inspect.signature(getattr(synthetic, name)).parameters) - given

    if kind == "zones_gradient":
        return own("zones") | {"gradient_" + p for p in own("gradient")}
    return own(kind)


def _check_timing(spec: TimingSpec, source: str) -> None:
    lo, hi = STEP_RANGE_S
    if not lo <= spec.control_period_s <= hi:
        raise ScenarioError(f"{source}: [timing] control_period_s must be in [{lo:g}, {hi:g}] s (SUMO's "
                            f"step), got {spec.control_period_s!r}")
    if not 0 < spec.plant_step_s <= spec.control_period_s:
        raise ScenarioError(f"{source}: [timing] plant_step_s must be > 0 and <= control_period_s, "
                            f"got {spec.plant_step_s}")
    ratio = spec.control_period_s / spec.plant_step_s
    if abs(ratio - round(ratio)) > 1e-9:
        raise ScenarioError(f"{source}: [timing] control_period_s ({spec.control_period_s}) must be a "
                            f"whole multiple of plant_step_s ({spec.plant_step_s})")
    _check_sumo_step(spec, source)
    limit = spec.max_sim_time_s
    if limit is not None and not spec.control_period_s <= limit <= MAX_SIM_TIME_S:
        raise ScenarioError(f"{source}: [timing] max_sim_time_s must be in [control_period_s, "
                            f"{MAX_SIM_TIME_S:g}] s, got {limit!r}")


def _check_sumo_step(spec: TimingSpec, source: str) -> None:
    step, period = spec.sumo_step_s, spec.control_period_s
    if step is None:
        return
    ratio = step / period  # a number: `services.sim.tables.build` checked its type
    if not (STEP_RANGE_S[0] <= step <= STEP_RANGE_S[1] and ratio >= 1 and abs(ratio - round(ratio)) <= 1e-9):
        raise ScenarioError(f"{source}: [timing] sumo_step_s must be a whole multiple of control_period_s "
                            f"({period:g} s) of at most {STEP_RANGE_S[1]:g} s, got {step!r}")


def files_named(scenario: Scenario) -> list[tuple[str, str]]:
    """The files the scenario reads, as (``[table] key``, path resolved against its folder)."""
    return [(f"[{table}] file", scenario.path(spec.file)) for table, spec in
            (("field", scenario.field), ("map", scenario.map)) if spec.file is not None]


def _check_output(spec: OutputSpec, timing: TimingSpec, source: str) -> None:
    control_hz = 1.0 / timing.control_period_s
    if not 0 < spec.log_rate_hz <= control_hz * (1 + 1e-9):
        raise ScenarioError(f"{source}: [output] log_rate_hz must be > 0 and <= the control rate "
                            f"({control_hz:g} Hz), got {spec.log_rate_hz}")
    if spec.units is not None and spec.units not in UNIT_SYSTEMS:
        raise ScenarioError(f"{source}: [output] units must be one of {', '.join(UNIT_SYSTEMS)}, got "
                            f"{spec.units!r}")
    if spec.points not in POINT_FORMATS:
        raise ScenarioError(f"{source}: [output] points must be one of {', '.join(POINT_FORMATS)}, "
                            f"got {spec.points!r}")
    track = [spec.track] if isinstance(spec.track, str) else spec.track
    if not (isinstance(spec.track, str) or (isinstance(track, (list, tuple)) and track)) or not all(
            isinstance(f, str) and f in (*TRACK_FORMATS, "none") for f in track) or (
            "none" in track and len(track) > 1):
        raise ScenarioError(f"{source}: [output] track must be one of {', '.join(TRACK_FORMATS)}, none, or "
                            f"a list of {' and '.join(TRACK_FORMATS)}, got "
                            f"{list(spec.track) if isinstance(spec.track, tuple) else spec.track!r}")
