"""World building: what a scenario builds before anything moves (field, coverage path, prescription).

Errors name the scenario file and its table. The prescription is always on a grid in the field's
metric CRS (its UTM zone), which is where the control core looks rates up.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

import numpy as np

from vrsim.common import MapError, ScenarioError, VehicleError, files
from vrsim.maps import Grid, read_map, synthetic
from vrsim.maps.units import rate_kind
from vrsim.services.sim.drive_job import DriveJob
from vrsim.services.sim.resolve import as_run
from vrsim.services.sim.scenario import Scenario, product_density_kg_l
from vrsim.vehicle import CoveragePath, Field, plan_coverage
from vrsim.vehicle.field import SLIVER_M2

MAP_MARGIN_M = 30.0  # synthetic maps extend this far beyond the field, so look-ahead stays on the map
# Memory of a run accounted part by part (`services.sim.bounded`, `vrsim run`), measured on the huge
# scenario and rounded up: per map cell (the as-applied rasters with their passes, the reference
# meters', the worked area, the coverage map, the figures' and outputs' temporaries), per tick of the
# longest stretch it holds (a headland loop: the track, control and landing arrays with temporaries),
# per tick kept (the metered product, the log) and the processes' code and libraries.
RUN_BYTES_PER_CELL = 1000
RUN_BYTES_PER_STRETCH_TICK = 3000
RUN_BYTES_PER_TICK = 16
RUN_BASE_BYTES = 400 * 2**20


@dataclass
class World:
    """What a scenario builds before anything moves: field, path and the prescription on its grid."""

    scenario: Scenario   # as run (`services.sim.as_run.as_run`)
    field: Field
    path: CoveragePath
    grid: Grid  # the prescription, in the field's metric CRS


def _build_field(scenario: Scenario) -> Field:
    spec = scenario.field
    if spec.from_map:
        try:
            return field_from_map(scenario.path(scenario.map.file), crs=scenario.map.crs,
                                  sliver_m2=spec.sliver_m2)
        except MapError as exc:
            raise VehicleError(f"from_map: {exc}") from None
    if spec.file is not None:
        return Field.from_file(scenario.path(spec.file), crs=spec.crs, union=spec.union,
                               sliver_m2=spec.sliver_m2)
    if spec.rectangle is not None:
        r = spec.rectangle
        return Field.rectangle(r["width_m"], r["length_m"], lat=r["lat"], lon=r["lon"])
    return Field.from_lonlat([tuple(p) for p in spec.polygon_lonlat])


def field_from_map(path: str, crs=None, layer: str | None = None, sliver_m2: float = SLIVER_M2) -> Field:
    """The field a zone prescription covers: the union of its zones (`vehicle.Field.from_polygons`:
    repaired in the field's UTM zone, holes kept, parts and holes under `sliver_m2` m^2 dropped).

    Raises
    ------
    MapError
        Not a zone file (a shapefile, zipped or not, GeoPackage or GeoJSON), no polygon, no CRS.
    VehicleError
        A union of several parts, or one over the field caps.
    """
    from vrsim.maps.zone_table import is_zone_file, read_zone_table

    if not os.path.exists(path):
        raise MapError(f"{path}: no such file or folder")
    if not is_zone_file(path):
        raise MapError(f"{path}: a field is taken from a zone map's polygons (a shapefile, zipped or not, "
                       "GeoPackage or GeoJSON); this one has none")
    table = read_zone_table(path, layer=layer, crs=crs, attributes=False)   # the polygons only: no GDAL
    if table.crs is None:
        raise MapError(f"{path}: the file does not state its CRS (no .prj); give one ([map] crs, --crs)")
    name = os.path.splitext(os.path.basename(path))[0]
    return Field.from_polygons(table.polygons, table.crs, name, sliver_m2, f"{path}: its zones' union")


def _build_prescription(scenario: Scenario, field: Field) -> Grid:
    """The prescription on a grid in the field's CRS; refuses a map that misses the field."""
    spec = scenario.map
    if spec.synthetic is not None:
        minx, miny, maxx, maxy = field.polygon.bounds
        bounds = (minx - MAP_MARGIN_M, miny - MAP_MARGIN_M, maxx + MAP_MARGIN_M, maxy + MAP_MARGIN_M)
        try:
            if spec.synthetic == "zones_gradient":
                return _zones_plus_gradient(bounds, field.crs, spec.cell_size_m, scenario.seed, spec.params)
            make = getattr(synthetic, spec.synthetic)
            return make(bounds=bounds, crs=field.crs, cell_size_m=spec.cell_size_m, seed=scenario.seed,
                        **spec.params)
        except (TypeError, ValueError) as exc:  # a parameter of the wrong shape, e.g. a 3-value range
            raise ScenarioError(f"{scenario.source}: [map] params {spec.params!r} do not fit "
                                f"synthetic {spec.synthetic!r}: {exc}") from None
    grid = read_map(scenario.path(spec.file), rate_field=spec.rate_field, cell_size_m=spec.cell_size_m,
                    crs=spec.crs, unit=spec.unit, density_kg_l=product_density_kg_l(scenario))
    if grid.quantity != "rate":
        raise MapError(f"{grid.source}: holds differences of rates in {grid.unit} (e.g. a run's error.tif), "
                       "not a prescription")
    if rate_kind(grid.unit) == "count":  # seeds/ha: as a mass rate with the seeds' mass, once here
        grid = grid.to_kg_ha(seed_mass_g=scenario.product.seed_mass_g)
    if grid.unit != "kg/ha":  # a volume or count rate the run cannot meter as mass
        need = ("density: [product] density_kg_l" if rate_kind(grid.unit) == "volume" else
                "seed mass: [product] thousand_seed_mass_g")
        raise MapError(f"{grid.source}: a {rate_kind(grid.unit)} rate ({grid.unit}) runs as a mass rate only "
                       f"with the product's {need}")
    grid.check_overlap(field.polygon, field.crs)
    if not grid.crs.equals(field.crs):
        grid = grid.reproject(field.crs, cell_size_m=spec.cell_size_m)
    return grid


def _zones_plus_gradient(bounds, crs, cell_size_m, seed, params) -> Grid:
    """The default scenario's map: sharp-edged zones tilted by a gradient.

    ``params`` holds `synthetic.zones` keywords and `synthetic.gradient` keywords prefixed with
    ``gradient_``; the gradient's mean is removed, so it tilts the zones without changing their mean.
    """
    zone_params = {k: v for k, v in params.items() if not k.startswith("gradient_")}
    grad_params = {k[len("gradient_"):]: v for k, v in params.items() if k.startswith("gradient_")}
    zones = synthetic.zones(bounds=bounds, crs=crs, cell_size_m=cell_size_m, seed=seed, **zone_params)
    grad = synthetic.gradient(bounds=bounds, crs=crs, cell_size_m=cell_size_m, seed=seed, **grad_params)
    tilt = grad.rates_kg_ha - grad.rates_kg_ha.mean()
    return dataclasses.replace(zones, rates_kg_ha=np.maximum(zones.rates_kg_ha + tilt, 0.0),
                               source="synthetic:zones_gradient")


def build_world(scenario: Scenario, planned: tuple[Field, CoveragePath] | None = None) -> World:
    """Field, prescription and coverage path (`plan_path`, unless `planned` holds what it gave), and
    the scenario as run (`services.sim.as_run.as_run`: every kind's default resolved), which the run
    consumes and its outputs show; errors name the scenario file and its table."""
    field, path = planned or plan_path(scenario)
    try:
        grid = _build_prescription(scenario, field)
    except MapError as exc:
        raise ScenarioError(f"{scenario.source}: [map] {exc}") from None
    return World(scenario=as_run(scenario), field=field, path=path, grid=grid)


def plan_path(scenario: Scenario) -> tuple[Field, CoveragePath]:
    """The field and the coverage path over it: all that SUMO drives.

    Refused before the path is planned: a run that would not fit in memory even accounted part by
    part (`_check_run_size`); after: a time limit the tractor cannot meet even at its top speed."""
    spec = scenario.field
    try:
        field = _build_field(scenario)
        _check_run_size(scenario, field)
        path = plan_coverage(field, scenario.implement.width_m, headland_passes=spec.headland_passes,
                             heading_deg=spec.heading_deg, turn_radius_m=spec.turn_radius_m)
    except VehicleError as exc:
        raise ScenarioError(f"{scenario.source}: [field] {exc}") from None
    _check_time_limit(scenario, path)
    return field, path


def _check_run_size(scenario: Scenario, field: Field) -> None:
    """Refuse a run that would not fit in memory even accounted part by part: its map's cells (the
    field's bounds and margin at ``[map] cell_size_m``), its longest stretch (a headland loop round the
    field) and the ticks of the path a field of this area and perimeter needs at this working width
    (swaths plus headland passes), `RUN_BYTES_PER_CELL` and the rest."""
    drive, period = scenario.tractor, scenario.timing.control_period_s
    tick_m = drive.working_speed_m_s * period
    path_m = field.polygon.area / scenario.implement.width_m \
        + field.polygon.length * (scenario.field.headland_passes + 1)
    ticks = path_m / tick_m
    minx, miny, maxx, maxy = field.polygon.bounds
    cell = scenario.map.cell_size_m
    cells = (maxx - minx + 2 * MAP_MARGIN_M) / cell * ((maxy - miny + 2 * MAP_MARGIN_M) / cell)
    need = (RUN_BASE_BYTES + cells * RUN_BYTES_PER_CELL + ticks * RUN_BYTES_PER_TICK
            + field.polygon.length / tick_m * RUN_BYTES_PER_STRETCH_TICK)
    files.check_memory(need, f"a run of about {ticks:,.0f} ticks ({path_m / 1000:,.0f} km at "
                       f"{drive.working_speed_m_s:g} m/s, {period:g} s per tick) over a map of about "
                       f"{cells:,.0f} cells of {cell:g} m", f"{scenario.source}: [field]", ScenarioError,
                       max_bytes=math.inf)


def _check_time_limit(scenario: Scenario, path: CoveragePath) -> None:
    limit, top = scenario.timing.max_sim_time_s, scenario.tractor.max_speed_m_s
    if limit is not None and limit < path.length_m / top:
        raise ScenarioError(f"{scenario.source}: [timing] max_sim_time_s = {limit:g} s cannot be met: the "
                            f"{path.length_m:,.0f} m path takes at least {path.length_m / top:,.1f} s at the "
                            f"tractor's top speed of {top:g} m/s")


def field_and_grid(scenario: Scenario) -> tuple[Field, Grid]:
    """The scenario's field and its prescription on the field's metric grid, without planning a
    path (what the map and controller services need)."""
    field = _build_field(scenario)
    return field, _build_prescription(scenario, field)


def driving(scenario: Scenario, path: CoveragePath):
    """A `vehicle.SumoDriver` on `path` with the scenario's tractor, tick and time limit
    (``[timing] max_sim_time_s``; unset, the driver derives it from the path), as a context manager.

    `vrsim run` and the vehicle service both drive through this (`services.sim.drive_job.DriveJob`),
    so they stop at the same limit with the same message; a `VehicleError` while driving becomes a
    `ScenarioError` naming the scenario.
    """
    return DriveJob.of(scenario, path).driving()
