"""The field run: map, tractor and controller in one loop.

Data flow of one control tick (see the README's picture)::

    SUMO pose --GNSS--> measured fix --look-ahead by the delivery delay--> landing point
    --map lookup--> rate kg/ha --with speed, width, kg/rev--> target shaft rpm --PID--> valve current
    --hydraulic plant--> shaft revolutions --x kg/rev--> kg metered --lands after the delay--> map

The control part (`ControlCore`: `run_track` over a run or a batch of ticks, `tick` for one) is
the one pure core that both `vrsim run` (the whole track) and the Zenoh controller service (each
lockstep batch, carrying its state over) call. The stages that do not feed back (driving, GNSS
noise, where product lands, the as-applied raster, the metrics) are vectorized over the whole run:
the vehicle's path does not depend on the metering, so SUMO can drive the whole path first and the
control loop follow it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from common import MapError, ScenarioError, VehicleError
from controller import PlantParams, build_loop
from maps import AsApplied, Grid, RatePolicy, read_map, synthetic
from services.sim.metrics import MapMetrics, TransitionMetrics, map_metrics, transitions
from services.sim.scenario import Scenario
from vehicle import CoveragePath, Field, Gnss, SpeedSensor, SumoDriver, plan_coverage

MAP_MARGIN_M = 30.0  # synthetic maps extend this far beyond the field, so look-ahead stays on the map
SPEED_SENSOR_SEED_OFFSET = 1  # the speed sensor's noise is seeded apart from the GNSS noise


@dataclass
class World:
    """What a scenario builds before anything moves: field, path and the prescription on its grid."""

    scenario: Scenario
    field: Field
    path: CoveragePath
    grid: Grid  # the prescription, in the field's metric CRS


def build_field(scenario: Scenario) -> Field:
    spec = scenario.field
    if spec.file is not None:
        return Field.from_file(scenario.path(spec.file), crs=spec.crs)
    if spec.rectangle is not None:
        r = spec.rectangle
        return Field.rectangle(r["width_m"], r["length_m"], lat=r["lat"], lon=r["lon"])
    return Field.from_lonlat([tuple(p) for p in spec.polygon_lonlat])


def build_prescription(scenario: Scenario, field: Field) -> Grid:
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
                    crs=spec.crs)
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


def build_world(scenario: Scenario) -> World:
    """Field, prescription and coverage path; errors name the scenario file and its table."""
    spec = scenario.field
    try:
        field = build_field(scenario)
        path = plan_coverage(field, scenario.implement.width_m, headland_passes=spec.headland_passes,
                             heading_deg=spec.heading_deg, turn_radius_m=spec.turn_radius_m)
    except VehicleError as exc:
        raise ScenarioError(f"{scenario.source}: [field] {exc}") from None
    try:
        grid = build_prescription(scenario, field)
    except MapError as exc:
        raise ScenarioError(f"{scenario.source}: [map] {exc}") from None
    return World(scenario=scenario, field=field, path=path, grid=grid)


def plant_for(scenario: Scenario) -> PlantParams:
    """The scenario's plant with the implement's transmission ratio and shaft-speed limit: the machine
    is described once, in ``[implement]``."""
    imp = scenario.implement
    return dataclasses.replace(scenario.plant, transmission_ratio=imp.transmission_ratio,
                               shaft_rpm_max=imp.shaft_rpm_max)


@dataclass
class TickOut:
    """What one control tick produces (all SI except rpm)."""

    landing_x_m: float
    landing_y_m: float
    prescribed_kg_ha: float  # the rate looked up at the predicted landing point
    target_shaft_rpm: float
    shaft_rpm: float
    shaft_rev: float  # metering-shaft revolutions during this period
    current_a: float
    metered_kg: float  # product through the meter this period (0 with the sections off)
    width_on_m: float  # working width of the sections that are on
    offset_m: float  # lateral offset of that width's centre, left of the heading


def hold_last(rate_kg_ha: np.ndarray, last_kg_ha: float) -> np.ndarray:
    """Replace NaN (unknown) rates by the last known one, starting from `last_kg_ha` (NaN: 0)."""
    known = ~np.isnan(rate_kg_ha)
    idx = np.maximum.accumulate(np.where(known, np.arange(rate_kg_ha.size), -1))
    start = 0.0 if math.isnan(last_kg_ha) else last_kg_ha
    return np.where(idx >= 0, rate_kg_ha[np.maximum(idx, 0)], start)


class ControlCore:
    """Control ticks: fix -> landing point -> rate -> target rpm -> PID + plant -> product.

    Deterministic and free of I/O; `vrsim run` (a whole track at once, `run_track`) and the
    controller service (one tick at a time, `tick`) run the same two stages:

    1. `targets`: where product metered now will land, the prescription there (with the map's
       policy off the map), and the target shaft speed. No feedback, so vectorized over ticks. The
       landing point is predicted by dead reckoning from the fix: product metered now lands
       `delivery_delay_s` later, when the implement has moved ``speed * delay`` along its heading.
    2. the closed loop (PID, valve, motor), one `ClosedLoop.step` per tick.
    """

    def __init__(self, grid: Grid, scenario: Scenario, field_polygon=None):
        self.grid = grid
        self.field_polygon = field_polygon  # sections whose centre would land outside it switch off
        self.implement = scenario.implement
        self.policy = RatePolicy(mode=scenario.map.policy,
                                 default_rate_kg_ha=scenario.map.default_rate_kg_ha)
        timing = scenario.timing
        self.loop = build_loop(plant_for(scenario), scenario.controller,
                               control_period_s=timing.control_period_s, plant_step_s=timing.plant_step_s,
                               n=1)
        self.last_rate_kg_ha = float("nan")

    def targets(self, x_m, y_m, heading_rad, speed_m_s, implement_on) -> dict[str, np.ndarray]:
        """Stage 1 over arrays of ticks (shape (n,)); advances the policy's memory."""
        lead_m = np.asarray(speed_m_s) * self.implement.delivery_delay_s
        lx = x_m + lead_m * np.cos(heading_rad)
        ly = y_m + lead_m * np.sin(heading_rad)
        found = self.grid.lookup(lx, ly)
        if self.policy.mode == "hold":
            rate = hold_last(found.rate_kg_ha, self.last_rate_kg_ha)
        else:
            rate = self.policy.apply(found.rate_kg_ha, found.inside)
        if rate.size:
            self.last_rate_kg_ha = float(rate[-1])
        width_on, offset = self.sections(lx, ly, heading_rad, implement_on)
        # Within the meter's speed range while applying; a zero rate or all sections off stop the shaft.
        wanted = self.implement.clip_shaft_rpm(self.implement.target_shaft_rpm(rate, speed_m_s, width_on))
        target = np.where(width_on > 0, wanted, 0.0)
        return {"landing_x_m": lx, "landing_y_m": ly, "prescribed_kg_ha": rate, "target_shaft_rpm": target,
                "width_on_m": width_on, "offset_m": offset}

    def sections(self, x_m, y_m, heading_rad, implement_on):
        """Working width of the sections that are on (m) and its centre's offset to the left (m).

        Section control as terminals do it: with the implement on, a section applies when its centre
        lands inside the field. The sections that are on are taken as one strip (they are contiguous
        on convex edges; on a notch this spreads a little product over the gap).
        """
        imp = self.implement
        on = np.asarray(implement_on, bool)
        if self.field_polygon is None:
            return np.where(on, imp.width_m, 0.0), np.zeros(on.shape)
        sec = imp.sections_on(self.field_polygon, x_m, y_m, heading_rad, on)
        count = sec.sum(axis=1)
        offsets = np.where(sec, imp.section_offsets_m, 0.0).sum(axis=1)
        return count * imp.section_width_m, np.divide(offsets, count, out=np.zeros(count.shape),
                                                      where=count > 0)

    def run_track(self, x_m, y_m, heading_rad, speed_m_s, implement_on,
                  progress=None) -> dict[str, np.ndarray]:
        """Both stages over a whole measured track; arrays of shape (n,) keyed as `CONTROL_KEYS`."""
        rec = self.targets(x_m, y_m, heading_rad, speed_m_s, implement_on)
        targets, n = rec["target_shaft_rpm"], len(x_m)
        rpm, rev, cur = np.empty(n), np.empty(n), np.empty(n)
        chunk = 20000
        for start in range(0, n, chunk):
            part = slice(start, min(n, start + chunk))
            out = self.loop.run(targets[part])
            rpm[part], rev[part], cur[part] = out.shaft_rpm[:, 0], out.shaft_rev[:, 0], out.current_a[:, 0]
            if progress is not None:
                progress(part.stop, n)
        rec.update(shaft_rpm=rpm, shaft_rev=rev, current_a=cur,
                   metered_kg=self._metered_kg(rev, rec["width_on_m"] > 0))
        return {key: rec[key] for key in CONTROL_KEYS}

    def tick(self, x_m: float, y_m: float, heading_rad: float, speed_m_s: float,
             implement_on: bool) -> TickOut:
        """Both stages for one tick."""
        t = self.targets(np.array([x_m]), np.array([y_m]), np.array([heading_rad]), np.array([speed_m_s]),
                         np.array([implement_on]))
        target, width_on = float(t["target_shaft_rpm"][0]), float(t["width_on_m"][0])
        out = self.loop.step(target)
        rev = float(out.shaft_rev[0])
        return TickOut(float(t["landing_x_m"][0]), float(t["landing_y_m"][0]),
                       float(t["prescribed_kg_ha"][0]), target, float(out.shaft_rpm[0]), rev,
                       float(out.current_a[0]),
                       float(self._metered_kg(np.array([rev]), np.array([width_on > 0]))[0]),
                       width_on, float(t["offset_m"][0]))

    def _metered_kg(self, shaft_rev, applying) -> np.ndarray:
        # Sections off close the gate: what the shaft turns then stays in the hopper. An underdamped
        # motor can swing briefly backwards when it brakes hard; a roller turning back meters nothing
        # (it does not lift product off the ground), so only forward revolutions count.
        forward = np.maximum(shaft_rev, 0.0)
        return np.where(np.asarray(applying, bool), self.implement.mass_kg(forward), 0.0)


CONTROL_KEYS = ("landing_x_m", "landing_y_m", "prescribed_kg_ha", "target_shaft_rpm", "shaft_rpm",
                "shaft_rev", "current_a", "metered_kg", "width_on_m", "offset_m")


@dataclass
class Landing:
    """Where the product metered in each tick landed, and the rates there along the track."""

    x0_m: np.ndarray
    y0_m: np.ndarray
    x1_m: np.ndarray
    y1_m: np.ndarray
    strip_length_m: np.ndarray
    distance_m: np.ndarray  # landing point's travelled distance at each tick
    prescribed_kg_ha: np.ndarray  # prescription at each strip's midpoint (true position)
    applied_kg_ha: np.ndarray  # metered kg over the strip's area (NaN: shorter than 1 cm, or sections off)


def land(grid: Grid, track: dict, metered_kg, width_on_m, offset_m, delay_s, period_s) -> Landing:
    """Product metered during [t, t + period] lands on the true path during the same span + delay,
    over the width of the sections that were on, shifted by their offset to the left."""
    time_s, x_m, y_m = track["time_s"], track["x_m"], track["y_m"]
    t0 = np.asarray(time_s) + delay_s
    hx = np.interp(t0, time_s, np.cos(track["heading_rad"]))
    hy = np.interp(t0, time_s, np.sin(track["heading_rad"]))
    norm = np.hypot(hx, hy)
    shift = np.divide(offset_m, norm, out=np.zeros(norm.shape), where=norm > 0)
    sx, sy = -hy * shift, hx * shift  # along the left normal
    x0, y0 = np.interp(t0, time_s, x_m) + sx, np.interp(t0, time_s, y_m) + sy
    x1, y1 = np.interp(t0 + period_s, time_s, x_m) + sx, np.interp(t0 + period_s, time_s, y_m) + sy
    length = np.hypot(x1 - x0, y1 - y0)
    area = np.asarray(width_on_m) * length
    with np.errstate(divide="ignore", invalid="ignore"):
        applied = np.where((length > 0.01) & (area > 0), metered_kg / area * 1e4, np.nan)
    rx = grid.lookup(0.5 * (x0 + x1), 0.5 * (y0 + y1)).rate_kg_ha
    return Landing(x0, y0, x1, y1, length, np.cumsum(length), rx, applied)


def merged_strips(landing: Landing, metered_kg, width_m, offset_m, cell_m: float):
    """Consecutive ticks' strips joined into strips up to half a cell long: (x0, y0, x1, y1, width, kg).

    A tick's strip (0.125 m at 9 km/h and 50 ms) is far shorter than a map cell; joining k of them
    (their ends meet exactly) spreads each group's product evenly over at most half a cell, which
    changes per-cell figures by a blur far below the cell size and cuts the raster work k-fold. A
    group also ends where the sections change, so a joined strip has one width and offset.
    """
    n = len(metered_kg)
    typical = float(np.median(landing.strip_length_m)) if n else 0.0
    k = max(1, int(0.5 * cell_m / typical)) if typical > 0 else 1
    change = np.flatnonzero((np.diff(width_m) != 0) | (np.diff(offset_m) != 0)) + 1
    starts = np.union1d(np.arange(0, n, k), change).astype(np.int64)
    ends = np.append(starts[1:], n) - 1
    return (landing.x0_m[starts], landing.y0_m[starts], landing.x1_m[ends], landing.y1_m[ends],
            np.asarray(width_m)[starts], np.add.reduceat(metered_kg, starts) if n else metered_kg)


def cells_in_field(grid: Grid, polygon) -> np.ndarray:
    """Boolean (rows, cols): cells whose centre lies inside the field polygon."""
    import shapely

    cols, rows = np.meshgrid(np.arange(grid.cols) + 0.5, np.arange(grid.rows) + 0.5)
    xs, ys = grid.transform @ (cols, rows)
    return shapely.contains_xy(polygon, xs, ys)


@dataclass
class RunResult:
    world: World
    track: dict
    measured_x_m: np.ndarray
    measured_y_m: np.ndarray
    measured_speed_m_s: np.ndarray
    control: dict
    landing: Landing
    as_applied: AsApplied
    in_field: np.ndarray
    map_metrics: MapMetrics
    transition_metrics: TransitionMetrics
    stage_s: dict
    summary: dict


def run(scenario: Scenario, progress=None) -> RunResult:
    """Run a scenario in process and return everything it measured."""
    stage = {}
    wall0 = clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        stage[name] = stage.get(name, 0.0) + now - clock
        clock = now

    world = build_world(scenario)
    lap("build_s")
    timing = scenario.timing
    with SumoDriver(world.path, scenario.tractor, step_s=timing.control_period_s, seed=scenario.seed,
                    max_time_s=timing.max_sim_time_s) as driver:
        track = driver.run_all()
    lap("sumo_s")
    x_meas, y_meas, v_meas = measure(scenario, track)
    lap("sensors_s")
    core = ControlCore(world.grid, scenario, world.field.polygon)
    control = core.run_track(x_meas, y_meas, track["heading_rad"], v_meas, track["implement_on"], progress)
    lap("control_s")
    summary, rest = account(world, track, control, wall0)
    lap("metrics_s")
    summary["wall_time_s"] = time.perf_counter() - wall0
    summary["realtime_factor"] = summary["sim_time_s"] / summary["wall_time_s"]
    summary["stage_s"] = stage
    return RunResult(world=world, track=track, measured_x_m=x_meas, measured_y_m=y_meas,
                     measured_speed_m_s=v_meas, control=control, stage_s=stage, summary=summary, **rest)


def sensors(scenario: Scenario) -> tuple[Gnss, SpeedSensor]:
    """The GNSS receiver and the ground-speed sensor the controller reads, seeded from the scenario."""
    return (Gnss(scenario.gnss, seed=scenario.seed),
            SpeedSensor(scenario.speed_sensor, seed=scenario.seed + SPEED_SENSOR_SEED_OFFSET))


def measure(scenario: Scenario, track: dict):
    """Measured x, y (GNSS) and ground speed (speed sensor) over a whole true track."""
    gnss, speed = sensors(scenario)
    x, y = gnss.measure(track["time_s"], track["x_m"], track["y_m"])
    return x, y, speed.measure(track["time_s"], track["speed_m_s"])


def account(world: World, track: dict, control: dict, wall0: float):
    """Land the metered product, build the as-applied raster and compute the summary."""
    scenario, grid = world.scenario, world.grid
    implement, timing = scenario.implement, scenario.timing
    width_on = control.get("width_on_m", np.where(track["implement_on"], implement.width_m, 0.0))
    offset = control.get("offset_m", np.zeros(len(width_on)))
    landing = land(grid, track, control["metered_kg"], width_on, offset, implement.delivery_delay_s,
                   timing.control_period_s)
    acc = AsApplied(grid)
    acc.add_strips(*merged_strips(landing, control["metered_kg"], width_on, offset, min(grid.cell_size)))
    in_field = cells_in_field(grid, world.field.polygon)
    cell_w, cell_h = grid.cell_size
    mm = map_metrics(grid.rates_kg_ha, acc.applied_kg_ha, acc.coverage_fraction, in_field,
                     abs(cell_w * cell_h) / 1e4, float(control["metered_kg"].sum()), acc.outside_kg)
    tm = transitions(track["time_s"], landing.distance_m, landing.prescribed_kg_ha, landing.applied_kg_ha,
                     np.asarray(track["implement_on"], bool))
    n = len(track["time_s"])
    summary = {
        "scenario": scenario.name,
        "field_area_ha": world.field.area_ha,
        "sim_time_s": n * timing.control_period_s,
        "wall_time_s": time.perf_counter() - wall0,
        "ticks": n,
        "realtime_factor": 0.0,
        "prescribed_kg": mm.prescribed_kg,
        "applied_kg": mm.applied_kg,
        "mass_balance_pct": mm.mass_balance_pct,
        "mae_kg_ha": mm.mae_kg_ha,
        "rmse_kg_ha": mm.rmse_kg_ha,
        "bias_kg_ha": mm.bias_kg_ha,
        "within_5pct_area_pct": mm.within_5pct_area_pct,
        "within_10pct_area_pct": mm.within_10pct_area_pct,
        "transition_time_s_mean": tm.time_s_mean,
        "transition_time_s_p95": tm.time_s_p95,
        "transition_distance_m_mean": tm.distance_m_mean,
        "transition_distance_m_p95": tm.distance_m_p95,
        "off_target_kg": mm.off_target_kg,
        "coverage_pct": mm.coverage_pct,
        "mae_pct": mm.mae_pct,
        "rmse_pct": mm.rmse_pct,
        "bias_pct": mm.bias_pct,
        "transitions": tm.count,
        "covered_cells": mm.covered_cells,
        "path_length_m": float(landing.distance_m[-1]) if n else 0.0,
        "seed": scenario.seed,
    }
    rest = dict(landing=landing, as_applied=acc, in_field=in_field, map_metrics=mm, transition_metrics=tm)
    return summary, rest
