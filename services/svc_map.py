"""The map service: the prescription map over Zenoh (``vrsim serve map``).

Keys (see docs/api.md): ``<prefix>/map/info`` (what ``vrsim map info --json`` prints),
``<prefix>/map/rate`` (one point from selector parameters ``lat``/``lon`` or ``x``/``y``, or a batch of
points from a JSON body) and ``<prefix>/map/load`` (scenario control loads a scenario's prescription).
The map is a file given with ``--map`` (then fixed) or the prescription of the current scenario on
the field's metric grid (what the controller looks up).
"""

from __future__ import annotations

import json
import threading

from common import ServiceError
from services import messages
from services.zenoh_common import Params, ZenohOptions, dumps, run_service, serve

MAX_BATCH_POINTS = 10_000_000


class MapService:
    """The handlers of the map service over one `maps.Grid` (swapped whole on `load`)."""

    def __init__(self, grid, fixed: bool):
        self.grid, self.sampler = grid, PointSampler(grid)
        self.fixed = fixed
        self.lock = threading.Lock()  # a load swaps the grid while queries may read it

    def info(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        _no_body(params, payload)
        return dumps(self.grid.info())

    def rate(self, params: Params, payload: bytes | None) -> bytes:
        grid = self.grid
        if payload:
            params.only()
            first, second, geo = messages.decode_points(payload, MAX_BATCH_POINTS)
            res = grid.lookup(first, second, crs="EPSG:4326" if geo else None)
            return messages.encode_rates(res.rate_kg_ha, res.inside, res.row, res.col)
        params.only("lat", "lon", "x", "y")
        geo = params.has("lat") or params.has("lon")
        if geo and (params.has("x") or params.has("y")):
            raise ServiceError(f"{params.key}: give either lat and lon, or x and y, not both")
        if geo:
            lat, lon = params.number("lat", -90.0, 90.0), params.number("lon", -180.0, 180.0)
            sample = self.sampler.lonlat(lon, lat)
        elif params.has("x") or params.has("y"):
            sample = self.sampler.xy(params.number("x"), params.number("y"))
        else:
            raise ServiceError(f"{params.key}: missing parameters: give lat and lon (WGS84) or x and y "
                               "(map CRS), or a JSON body of points")
        return json.dumps(sample, separators=(",", ":")).encode()

    def load(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        start = messages.RunStart.from_json(payload)
        if self.fixed:
            return dumps({"loaded": False, "reason": "the map service serves a fixed --map file"})
        grid = scenario_grid(*_parse(start))
        sampler = PointSampler(grid)
        with self.lock:
            self.grid, self.sampler = grid, sampler
        return dumps({"loaded": True, "source": grid.source, "rows": grid.rows, "cols": grid.cols})

    def handlers(self) -> dict:
        return {"info": self.info, "rate": self.rate, "load": self.load}


class PointSampler:
    """`maps.Grid.sample` for one point at a few microseconds instead of ~80 (numpy's per-call cost
    on scalars dominates a single query). The same arithmetic as `Grid.lookup` and `Grid.rate_at`
    (offset times the precomputed inverse cell size, truncated), so the cell is the same to the bit;
    lat/lon go through the same cached transformer as ``lookup(..., crs="EPSG:4326")``.
    """

    def __init__(self, grid):
        from maps.crs import WGS84, transformer

        t = grid.transform
        self.x0, self.inv_dx, self.y0, self.inv_dy = t.c, 1.0 / t.a, t.f, 1.0 / -t.e
        self.rates, self.rows, self.cols = grid.rates_kg_ha, grid.rows, grid.cols
        self.to_grid = None if grid.crs == WGS84 else transformer(WGS84, grid.crs).transform

    def xy(self, x: float, y: float) -> dict:
        fc = (x - self.x0) * self.inv_dx
        fr = (self.y0 - y) * self.inv_dy
        if 0.0 <= fc < self.cols and 0.0 <= fr < self.rows:
            row, col = int(fr), int(fc)
            rate = float(self.rates[row, col])
            return {"rate_kg_ha": rate if rate == rate else None, "inside": True, "row": row, "col": col}
        return {"rate_kg_ha": None, "inside": False, "row": None, "col": None}

    def lonlat(self, lon: float, lat: float) -> dict:
        if self.to_grid is None:
            return self.xy(lon, lat)
        x, y = self.to_grid(lon, lat, errcheck=False)
        return self.xy(float(x), float(y))


def _no_body(params: Params, payload: bytes | None) -> None:
    if payload:
        raise ServiceError(f"{params.key}: takes no body")


def _parse(start: messages.RunStart):
    from services import scenario

    return (scenario.parse(start.scenario_text, start.source, start.base_dir),)


def scenario_grid(sc):
    """The scenario's prescription on the field's metric grid (what `ControlCore` looks up)."""
    return field_and_grid(sc)[1]


def field_and_grid(sc):
    """The scenario's `vehicle.Field` and its prescription on the field's metric grid."""
    from services.run import build_field, build_prescription

    field = build_field(sc)
    return field, build_prescription(sc, field)


def file_grid(path: str, rate_field=None, cell_size_m=None, crs=None):
    import maps

    return maps.read_map(path, rate_field=rate_field, cell_size_m=cell_size_m, crs=crs)


def main(options: ZenohOptions, grid, fixed: bool, stop: threading.Event | None = None) -> None:
    """Serve ``grid`` until SIGINT/SIGTERM (or ``stop``)."""
    svc = MapService(grid, fixed)
    keys = options.keys

    def declare(session):
        return [serve(session, keys.map_ns, svc.handlers(), f"{keys.prefix}/map/", "map")]

    run_service("map", options, declare, stop=stop)
