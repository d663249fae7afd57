"""Driving a coverage path in SUMO (libsumo, in-process) and reading the implement's pose each tick.

SUMO reports the vehicle's front bumper. The implement's reference point trails it by
``DriveConfig.implement_offset_m`` along the path, so the driver reads the route index and lane
position (one planned segment per edge, lane position scaled to planned arc length), subtracts the
offset, and looks the arc length up on the planned polyline: reported positions lie on the planned
path by construction, and SUMO's own junction cut-backs and rounding never leak into them.

SUMO may step at a multiple of the tick (``step_s = m * tick_s``): the ticks between two of its steps
get the arc length and speed interpolated linearly in time (`ticks_between`), then go through the same
look-up on the planned polyline, so they stay on the path in turns too (docs/model.md, "SUMO's step",
gives what that costs in position).

Speed: swath and headland edges allow ``working_speed * (1 + variation)``; the tractor's own
maximum speed follows a slow, seeded Gauss-Markov factor (clipped to +-``speed_variation_pct``)
updated every ``speed_update_s``; turn edges are limited to ``turn_speed_m_s`` and SUMO brakes
ahead of them with the vehicle type's deceleration.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from vrsim.common.checks import check_number, check_positive
from vrsim.common.errors import VehicleError
from vrsim.vehicle.coverage import CoveragePath
from vrsim.vehicle.network import Network, build_network, import_sumo_module
from vrsim.vehicle.track import ticks_between, track_on_path

_VEH, _TYPE, _ROUTE = "tractor", "tractor", "coverage"
STEP_RANGE_S = (0.001, 1.0)  # SUMO's simulation step (by default the control period), s
MAX_SEED = 2**31 - 1  # SUMO takes its --seed as a C int
MAX_WORKING_SPEED_M_S = 15.0  # 54 km/h: a faster working speed is not a field speed


@dataclass(frozen=True)
class DriveConfig:
    """How the tractor drives.

    Attributes
    ----------
    working_speed_m_s : float
        Nominal speed on swaths and headland passes, m/s.
    turn_speed_m_s : float
        Speed limit in turns, m/s.
    headland_speed_m_s : float, optional
        Speed limit on headland passes, m/s (default: the working speed, with its variation).
    speed_variation_pct : float
        Bound of the slow speed variation around the working speed, percent (0 = none).
    speed_variation_tau_s : float
        Correlation time of that variation, s.
    speed_update_s : float
        How often the tractor's target speed is updated, s.
    accel_m_s2, decel_m_s2 : float
        Acceleration and (comfortable) deceleration, m/s^2.
    vehicle_length_m : float
        Length of the tractor, m.
    implement_offset_m : float
        Distance from the tractor's front bumper back to the implement's reference point (the
        spreader discs), m; at least the vehicle length.
    """

    working_speed_m_s: float = 2.5
    turn_speed_m_s: float = 1.2
    headland_speed_m_s: float | None = None
    speed_variation_pct: float = 5.0
    speed_variation_tau_s: float = 20.0
    speed_update_s: float = 1.0
    accel_m_s2: float = 0.8
    decel_m_s2: float = 1.5
    vehicle_length_m: float = 5.0
    implement_offset_m: float = 6.5

    def __post_init__(self):
        for name in ("working_speed_m_s", "turn_speed_m_s", "speed_variation_tau_s", "speed_update_s",
                     "accel_m_s2", "decel_m_s2", "vehicle_length_m", "implement_offset_m"):
            _require(name, getattr(self, name), lo=0.0, lo_open=True)
        _require("speed_variation_pct", self.speed_variation_pct, lo=0.0, hi=50.0)
        if self.headland_speed_m_s is not None:
            _require("headland_speed_m_s", self.headland_speed_m_s, lo=0.0, lo_open=True)
        if self.implement_offset_m < self.vehicle_length_m:
            raise VehicleError(f"DriveConfig: implement_offset_m={self.implement_offset_m} must be >= "
                               f"vehicle_length_m={self.vehicle_length_m} (the implement trails the tractor)")
        if self.working_speed_m_s > MAX_WORKING_SPEED_M_S:
            raise VehicleError(f"DriveConfig: working_speed_m_s={self.working_speed_m_s} is not a field "
                               f"speed (> {MAX_WORKING_SPEED_M_S:g} m/s)")

    @property
    def max_speed_m_s(self) -> float:
        """Highest speed the tractor may reach, m/s."""
        return max(self.working_speed_m_s * (1 + self.speed_variation_pct / 100), self.turn_speed_m_s)

    def edge_speeds_m_s(self, kinds) -> list:
        """Speed limit per segment kind: turns at turn speed, headland passes at headland speed (if
        set), swaths at the maximum (the tractor's own varying maximum speed governs there)."""
        limits = {"turn": self.turn_speed_m_s, "headland": self.headland_speed_m_s or self.max_speed_m_s}
        return [limits.get(k, self.max_speed_m_s) for k in kinds]


def _require(name, value, lo=None, hi=None, lo_open=False):
    check_number(value, f"DriveConfig: {name}", VehicleError, lo=lo, hi=hi, lo_open=lo_open)


class Pose(NamedTuple):
    """The implement's state at one tick (a named tuple: built ~10x faster than a frozen dataclass,
    which matters at 130 000 ticks a run; ``pose._asdict()`` gives a dict).

    Attributes
    ----------
    time_s : float
        Simulation time, s.
    x_m, y_m : float
        Implement reference point on the planned path, field CRS metres.
    heading_rad : float
        Direction of travel, math convention: radians counter-clockwise from +x (east).
    speed_m_s : float
        Ground speed, m/s.
    implement_on : bool
        Sections on (working segment) or off (turn, or past the end of the path).
    segment_index : int
        Index into ``path.segments``.
    s_m : float
        Arc length along the path, m.
    """

    time_s: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_m_s: float
    implement_on: bool
    segment_index: int
    s_m: float


class SpeedVariation:
    """Seeded, slow speed factor ``1 + pct/100 * g``, g a clipped Gauss-Markov process in [-1, 1].

    ``g`` has a stationary standard deviation of 0.5 and correlation time ``tau_s``; one value per
    update of period ``dt_s`` (`next`). The same seed gives the same sequence.
    """

    def __init__(self, pct: float, tau_s: float, dt_s: float, seed: int):
        self._rng = np.random.default_rng(seed)
        self._a = math.exp(-dt_s / tau_s)
        self._b = 0.5 * math.sqrt(1 - self._a ** 2)
        self._g = 0.5 * float(self._rng.standard_normal())
        self._pct = pct

    def next(self) -> float:
        """The next speed factor (dimensionless)."""
        factor = 1.0 + self._pct / 100.0 * min(1.0, max(-1.0, self._g))
        self._g = self._a * self._g + self._b * float(self._rng.standard_normal())
        return factor


def import_libsumo():
    """libsumo, imported without its side effect on the process's PROJ settings
    (`vehicle.network.import_sumo_module`)."""
    return import_sumo_module("libsumo")


class SumoDriver:
    """Drive a `CoveragePath` in SUMO through libsumo; one open driver per process.

    Parameters
    ----------
    path : CoveragePath
    drive : DriveConfig, optional
    step_s : float
        SUMO step length, s.
    seed : int
        Seeds SUMO and the speed variation.
    cache_dir : str, optional
        Network cache (default ``$VRSIM_CACHE/sumo`` or ``~/.cache/vrsim/sumo``).
    max_time_s : float, optional
        Simulated time after which an unfinished drive is an error (a stalled tractor); default
        10 x the time to drive the path at the slowest configured speed, plus 60 s.
    tick_s : float, optional
        The period of the poses the driver reports (the control period), s; `step_s` must be a whole
        multiple of it. Default: `step_s` (every tick is a SUMO step; nothing is interpolated).

    Use as a context manager; `step` returns one `Pose` per tick until `finished`, `run_all` drives
    the whole path into arrays. The network is built (or fetched from the cache) in the constructor.
    """

    _open: SumoDriver | None = None  # libsumo holds one simulation per process

    def __init__(self, path: CoveragePath, drive: DriveConfig | None = None, step_s: float = 0.05,
                 seed: int = 1, cache_dir: str | None = None, max_time_s: float | None = None,
                 tick_s: float | None = None):
        if not isinstance(path, CoveragePath):
            raise VehicleError(f"SumoDriver: path must be a CoveragePath, got {type(path).__name__}")
        drive = drive or DriveConfig()
        if not isinstance(drive, DriveConfig):
            raise VehicleError(f"SumoDriver: drive must be a DriveConfig, got {type(drive).__name__}")
        check_number(step_s, "SumoDriver: step_s", VehicleError, lo=STEP_RANGE_S[0], hi=STEP_RANGE_S[1],
                     unit="s")
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or not 0 <= seed <= MAX_SEED:
            raise VehicleError(f"SumoDriver: seed must be an integer in [0, {MAX_SEED}], got {seed!r}")
        if max_time_s is None:
            slowest = min(drive.turn_speed_m_s, drive.working_speed_m_s, drive.headland_speed_m_s or math.inf)
            max_time_s = 10 * path.length_m / slowest + 60.0
        else:
            check_positive(max_time_s, "SumoDriver: max_time_s", VehicleError, unit="s")
        self.path, self.drive, self.step_s, self.seed = path, drive, float(step_s), int(seed)
        self.tick_s, self._ratio = _tick_ratio(self.step_s, tick_s)
        self.max_time_s = float(max_time_s)
        self.network: Network = build_network(path.segments, drive.edge_speeds_m_s(path.kinds()),
                                              lead_out_m=drive.implement_offset_m + 10.0,
                                              cache_dir=cache_dir)
        self._ls = None
        self.finished = False
        # Plain lists for the per-tick scalar lookup (bisect on a list beats numpy on scalars).
        self._s = path.s_m.tolist()
        self._x, self._y = path.xy[:, 0].tolist(), path.xy[:, 1].tolist()
        d = np.diff(path.xy, axis=0)
        self._h = np.arctan2(d[:, 1], d[:, 0]).tolist()
        self._seg_start = path.seg_start_m.tolist()
        self._on = [seg.implement_on for seg in path.segments]

    # --- lifecycle -------------------------------------------------------------------------------
    def __enter__(self) -> SumoDriver:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        """Start SUMO, insert the tractor with its implement at the start of the path."""
        if SumoDriver._open is not None:
            raise VehicleError("SumoDriver: another SUMO simulation is open in this process "
                               "(libsumo runs one per process); close it first")
        libsumo = import_libsumo()  # heavy; imported only when a simulation starts
        SumoDriver._open = self
        self._ls = libsumo
        try:
            libsumo.start(["sumo", "-n", self.network.net_file, "--step-length", repr(self.step_s),
                           "--seed", str(self.seed), "--begin", "0", "--no-step-log", "true",
                           "--no-warnings", "true", "--duration-log.disable", "true",
                           "--time-to-teleport", "-1", "--xml-validation", "never"])
        except libsumo.TraCIException as exc:
            SumoDriver._open, self._ls = None, None
            raise VehicleError(f"SUMO could not load {self.network.net_file}: {exc}") from None
        try:
            self._setup_vehicle()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop SUMO (idempotent)."""
        if self._ls is not None:
            self._ls.close()
            self._ls = None
            SumoDriver._open = None

    def _setup_vehicle(self) -> None:
        ls, drive = self._ls, self.drive
        ls.vehicletype.copy("DEFAULT_VEHTYPE", _TYPE)
        ls.vehicletype.setLength(_TYPE, drive.vehicle_length_m)
        ls.vehicletype.setAccel(_TYPE, drive.accel_m_s2)
        ls.vehicletype.setDecel(_TYPE, drive.decel_m_s2)
        ls.vehicletype.setEmergencyDecel(_TYPE, max(drive.decel_m_s2 * 2, 4.0))
        ls.vehicletype.setImperfection(_TYPE, 0.0)  # no random dawdling: variation is ours, seeded
        ls.vehicletype.setSpeedDeviation(_TYPE, 0.0)
        ls.vehicletype.setSpeedFactor(_TYPE, 1.0)
        ls.vehicletype.setMaxSpeed(_TYPE, drive.max_speed_m_s)
        edges = self.network.edge_ids
        sumo_len = np.array([ls.lane.getLength(f"{e}_0") for e in edges])
        planned = self.network.edge_length_m
        # SUMO stores lengths to 0.01 m; scale lane positions back to planned arc length.
        self._scale = (planned / sumo_len).tolist()
        # Start where the implement sits at s = 0: the front bumper is implement_offset_m ahead.
        offset = drive.implement_offset_m
        starts = np.concatenate([[0.0], np.cumsum(planned)])
        k0 = int(np.searchsorted(starts, offset, side="right") - 1)
        self._k0, self._edge_start = k0, starts.tolist()
        ls.route.add(_ROUTE, list(edges[k0:]))
        ls.vehicle.add(_VEH, _ROUTE, typeID=_TYPE, depart="now", departLane="0",
                       departPos=f"{(offset - starts[k0]) / self._scale[k0]:.6f}", departSpeed="0")
        self._speed = SpeedVariation(drive.speed_variation_pct, drive.speed_variation_tau_s,
                                     drive.speed_update_s, self.seed)
        self._update_every = max(1, round(drive.speed_update_s / self.step_s))
        self._tick = 0  # SUMO steps so far
        self._last = (0.0, 0.0, 0.0)  # the last SUMO sample (time_s, s_m, speed_m_s): at rest at s = 0
        self._queued, self._ticks = [], None  # `step` with a coarser SUMO step: ticks not yet returned
        self.finished = False
        # `_advance` calls the C++ functions behind libsumo's Python wrappers (`simulationStep`,
        # `vehicle.getSpeed`, ...), which add a Python call each, and `simulationStep` a pass over step
        # listeners (vrsim adds none), to the four calls a tick makes: the same calls, a fifth less time.
        from libsumo import _libsumo as c

        self._calls = (c.simulation_step, c.vehicle_getRouteIndex, c.vehicle_getLanePosition,
                       c.vehicle_getSpeed, c.vehicle_setMaxSpeed)

    # --- driving ---------------------------------------------------------------------------------
    def _advance(self):
        """One SUMO step; returns (time_s, s_m, speed_m_s) of the implement, or None once gone."""
        step, route_index, lane_position, speed, set_max_speed = self._calls
        step(0.0)
        if self._tick % self._update_every == 0:  # after the step: the tractor is inserted in step 1
            set_max_speed(_VEH, self.drive.working_speed_m_s * self._speed.next())
        self._tick += 1
        try:
            k = route_index(_VEH) + self._k0
            s = self._edge_start[k] + lane_position(_VEH) * self._scale[k]
            v = speed(_VEH)
        except self._ls.TraCIException:  # arrived: the lead-out edge ended
            return None
        return self._tick * self.step_s, s - self.drive.implement_offset_m, v

    def _require_open(self):
        if self._ls is None:
            raise VehicleError("SumoDriver: not open; use it as `with SumoDriver(...) as drv:`")
        if self.finished:
            raise VehicleError("SumoDriver: the path is finished")

    def step(self) -> Pose:
        """Advance one tick and return the implement's `Pose`; sets `finished` at the path's end.

        Raises `VehicleError` if the path is not finished by ``max_time_s``.
        """
        self._require_open()
        if self._ratio > 1:
            return self._step_interpolated()
        if self._tick * self.step_s >= self.max_time_s:
            raise self._not_finished()
        got = self._advance()
        length = self._s[-1]
        if got is None or got[1] >= length:
            self.finished = True
            t = got[0] if got else self._tick * self.step_s
            return self._pose(t, length, got[2] if got else 0.0, force_off=True)
        return self._pose(*got)

    def _step_interpolated(self) -> Pose:
        """`step` when SUMO steps at a multiple of the tick: the ticks of `run_parts`, one at a time."""
        if not (self._queued and self._queued[0]):
            self._ticks = self._ticks or self._tick_parts(self._ratio)
            self._queued = [tuple(a.tolist()) for a in next(self._ticks, ((), (), ()))]
        length = self._s[-1]
        if not self._queued[0]:  # the tractor left the network before the implement reached the end
            self.finished = True
            return self._pose(self._last[0], length, 0.0, force_off=True)
        t, s, v = (values[0] for values in self._queued)
        self._queued = [values[1:] for values in self._queued]
        self.finished = s >= length
        return self._pose(t, min(s, length), v, force_off=self.finished)

    def _pose(self, t, s, v, force_off=False) -> Pose:
        s = max(0.0, s)
        i = min(max(bisect.bisect_right(self._s, s) - 1, 0), len(self._s) - 2)
        ds = self._s[i + 1] - self._s[i]
        f = (s - self._s[i]) / ds if ds > 0 else 0.0
        seg = min(max(bisect.bisect_right(self._seg_start, s) - 1, 0), len(self._on) - 1)
        return Pose(t, self._x[i] + f * (self._x[i + 1] - self._x[i]),
                    self._y[i] + f * (self._y[i + 1] - self._y[i]), self._h[i], v,
                    self._on[seg] and not force_off, seg, s)

    def _not_finished(self) -> VehicleError:
        return VehicleError(f"SumoDriver: the tractor did not finish the {self.path.length_m:.0f} m path "
                            f"within max_time_s={self.max_time_s:g} s of simulated time")

    def run_all(self) -> dict:
        """Drive the whole path (or the rest of it) and return per-tick arrays.

        Returns
        -------
        dict of ndarray, shape (n,)
            ``time_s``, ``s_m``, ``x_m``, ``y_m``, ``heading_rad`` (math convention), ``speed_m_s``,
            ``implement_on`` (bool), ``segment_index`` (int): `track_on_path` of the whole drive.

        Raises
        ------
        VehicleError
            If the tractor has not finished after ``max_time_s``, e.g. because it stalled.
        """
        expected = self.path.length_m / (self.drive.working_speed_m_s * self.tick_s)
        parts = list(self.run_parts(int(2 * expected) + 1000))
        time_s, s_m, speed_m_s = (np.concatenate([p[k] for p in parts]) for k in range(3))
        return track_on_path(self.path, time_s, s_m, speed_m_s)

    def run_parts(self, ticks: int):
        """Drive the whole path (or the rest of it), yielding what SUMO reports every `ticks` ticks:
        ``(time_s, s_m, speed_m_s)`` arrays of up to `ticks` ticks (the implement's arc length along
        the path, not yet clipped to it; `track_on_path` makes a track of them, part by part or whole).
        With SUMO stepping at a multiple of the tick, the ticks between its steps are interpolated
        (`ticks_between`), up to the first that reaches the path's end.

        Raises `VehicleError` once the tractor has not finished after ``max_time_s``.
        """
        self._require_open()
        yield from self._tick_parts(ticks) if self._ratio > 1 else self._sumo_parts(ticks)

    def _tick_parts(self, ticks: int):
        """`run_parts` when SUMO steps at `_ratio` ticks: each part of SUMO's steps, interpolated."""
        length = self._s[-1]
        for t, s, v in self._sumo_parts(max(1, ticks // self._ratio)):
            if not len(t):  # an empty drive: one empty part, as SUMO's
                yield t, s, v
                continue
            part = ticks_between(self._last, (t, s, v), self.tick_s)
            self._last = (float(t[-1]), float(s[-1]), float(v[-1]))
            reached = np.flatnonzero(part[1] >= length)
            yield tuple(a[:reached[0] + 1] for a in part) if reached.size else part

    def _sumo_parts(self, ticks: int):
        """SUMO's own steps, in parts of up to `ticks` steps (`run_parts` when a tick is a step).

        `_advance`'s step inlined, into lists (a C call per value, where numpy's item assignment is
        several): the same numbers, a quarter less of the drive's time outside SUMO.

        The route index is asked only when the lane position says the edge may have changed: on one
        lane SUMO moves the tractor by ``pos += speed * step`` (Euler), the same double operation as
        here; on a next lane the lengths of the lanes left (each at least SUMO's 0.01 m, far above a
        double's rounding) are taken off, so it cannot equal ``last + speed * step``. Any other
        difference (or a SUMO that rounds its update otherwise) only asks SUMO again: the same
        numbers, one C call of four saved per tick."""
        max_ticks = max(int(self.max_time_s / self.step_s) - self._tick, 1)
        step, route_index, lane_position, speed, set_max_speed = self._calls
        edge_start, scale, k0, offset = self._edge_start, self._scale, self._k0, self.drive.implement_offset_m
        every, working, factor, gone = self._update_every, self.drive.working_speed_m_s, self._speed.next, \
            self._ls.TraCIException
        length, tick, sent, s_list, v_list = self._s[-1], self._tick, 0, [], []
        first, last_tick, step_s = tick, tick + max_ticks, self.step_s
        append_s, append_v = s_list.append, v_list.append
        k, last_lane_m = None, math.nan  # nan: the first tick asks for the route index
        while True:
            step(0.0)
            if tick % every == 0:  # after the step: the tractor is inserted in step 1
                set_max_speed(_VEH, working * factor())
            tick += 1
            try:
                lane_m = lane_position(_VEH)
                v = speed(_VEH)
                if lane_m != last_lane_m + v * step_s:  # perhaps on another edge: ask SUMO
                    k = route_index(_VEH) + k0
            except gone:  # arrived: the lead-out edge ended
                break
            last_lane_m = lane_m
            s = edge_start[k] + lane_m * scale[k] - offset
            if tick > last_tick:
                self._tick = tick
                raise self._not_finished()
            append_s(s)
            append_v(v)
            if s >= length:
                break
            if len(s_list) == ticks:
                self._tick = tick
                yield self._part(first, s_list, v_list)
                first, sent = tick, sent + 1
                s_list.clear()
                v_list.clear()
        self._tick = tick
        self.finished = True
        if s_list or not sent:  # no empty last part, but an empty drive is one (empty) part
            yield self._part(first, s_list, v_list)

    def _part(self, first: int, s_list: list, v_list: list):
        """(time_s, s_m, speed_m_s) arrays of the steps after step `first`."""
        return np.arange(first + 1, first + 1 + len(s_list)) * self.step_s, np.array(s_list), np.array(v_list)


def _tick_ratio(step_s: float, tick_s: float | None) -> tuple[float, int]:
    """The tick and how many ticks one SUMO step spans; a tick that does not divide the step is refused."""
    if tick_s is None:
        return step_s, 1
    check_number(tick_s, "SumoDriver: tick_s", VehicleError, lo=STEP_RANGE_S[0], hi=step_s, unit="s")
    ratio = round(step_s / tick_s)
    if abs(step_s / tick_s - ratio) > 1e-9:
        raise VehicleError(f"SumoDriver: step_s={step_s:g} s must be a whole multiple of tick_s={tick_s:g} s")
    return float(tick_s), ratio
