"""The map service: the prescription map over Zenoh (``vrsim serve map``).

Keys (see docs/api.md): ``<prefix>/map/info`` (what ``vrsim map info --json`` prints),
``<prefix>/map/rate`` (one point from selector parameters ``lat``/``lon`` or ``x``/``y``, or a batch of
points from a JSON body) and ``<prefix>/map/load`` (scenario control loads a scenario's prescription).
The map is a file given with ``--map`` (then fixed) or the prescription of the current scenario on
the field's metric grid (what the controller looks up).
"""

from __future__ import annotations

import threading

from vrsim.common import ServiceError
from vrsim.maps.units import KG_HA
from vrsim.services.bus import messages
from vrsim.services.bus.config import ServiceConfig
from vrsim.services.bus.dataroot import DataRoot
from vrsim.services.bus.serving import Params, body_limit, run_service, serve
from vrsim.services.outputs.encode import dumps


class _MapService:
    """The handlers of the map service over one `maps.Grid` (swapped whole on `load`)."""

    def __init__(self, grid, fixed: bool, data: DataRoot):
        self.grid = grid  # a load rebinds it whole; a query reads it once
        self.fixed = fixed
        self.data = data

    def info(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        _no_body(params, payload)
        return dumps(self.grid.info())

    @body_limit(messages.MAX_POINTS_BYTES)
    def rate(self, params: Params, payload: bytes | None) -> bytes:
        grid = self.grid
        if payload:
            params.only()
            first, second, geo = messages.decode_points(payload, messages.max_points(grid.map_unit))
            res = grid.lookup(first, second, crs="EPSG:4326" if geo else None)
            return messages.encode_rates(res.rate_kg_ha if grid.unit == KG_HA else None,
                                         grid.in_map_unit(res.rate_kg_ha), grid.map_unit, res.inside, res.row,
                                         res.col)
        params.only("lat", "lon", "x", "y")
        geo = params.has("lat") or params.has("lon")
        if geo and (params.has("x") or params.has("y")):
            raise ServiceError(f"{params.key}: give either lat and lon, or x and y, not both")
        if geo:
            lat, lon = params.number("lat", -90.0, 90.0), params.number("lon", -180.0, 180.0)
            sample = grid.sample(lat=lat, lon=lon)
        elif params.has("x") or params.has("y"):
            sample = grid.sample(x=params.number("x"), y=params.number("y"))
        else:
            raise ServiceError(f"{params.key}: missing parameters: give lat and lon (WGS84) or x and y "
                               "(map CRS), or a JSON body of points")
        return dumps(_with_units(grid, sample))

    def load(self, params: Params, payload: bytes | None) -> bytes:
        params.only()
        start = messages.RunStart.from_json(payload)
        if self.fixed:
            return dumps({"loaded": False, "reason": "the map service serves a fixed --map file"})
        grid = _scenario_grid(self.data.scenario(start.scenario_text, start.source, start.base_dir))
        self.grid = grid
        return dumps({"loaded": True, "source": grid.source, "rows": grid.rows, "cols": grid.cols})

    def handlers(self) -> dict:
        return {"info": self.info, "rate": self.rate, "load": self.load}


def _with_units(grid, sample: dict) -> dict:
    """A `maps.Grid.sample` of `grid` as a `messages.MapRate`: the rate also in the map's own unit."""
    value = sample["rate_kg_ha"]
    rate = None if value is None else float(grid.in_map_unit(value))
    return {"rate_kg_ha": value if grid.unit == KG_HA else None, "rate": rate, "rate_unit": grid.map_unit,
            **{k: sample[k] for k in ("inside", "row", "col")}}


def _no_body(params: Params, payload: bytes | None) -> None:
    if payload:
        raise ServiceError(f"{params.key}: takes no body")


def _scenario_grid(sc):
    """The scenario's prescription on the field's metric grid (what `ControlCore` looks up)."""
    from vrsim.services.sim.world import field_and_grid

    return field_and_grid(sc)[1]


def _configured_grid(config: ServiceConfig):
    """The map to serve and whether it is fixed: ``config.map_file``, else the prescription of
    ``config.scenario`` (a file or built-in name; None: the built-in default)."""
    if config.map_file is not None:
        from vrsim import maps

        return maps.read_map(config.map_file, rate_field=config.rate_field, cell_size_m=config.cell_size_m,
                             crs=config.crs, unit=config.unit), True
    from vrsim.services.sim import scenario

    return _scenario_grid(scenario.load(config.scenario)), False


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Serve the configured map until SIGINT/SIGTERM (or ``stop``)."""
    svc = _MapService(*_configured_grid(config), DataRoot.of(config))
    keys = config.zenoh.keys

    def declare(session):
        return [serve(session, keys.map_ns, svc.handlers(), f"{keys.prefix}/map/", "map")]

    run_service("map", config.zenoh, declare, stop=stop)
    return 0
