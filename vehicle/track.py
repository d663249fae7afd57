"""A drive's per-tick track: from SUMO's samples (`ticks_between`, `track_on_path`), and its validation,
shared by the sensors' vectorized `measure` forms (`track_arrays`)."""

from __future__ import annotations

import numpy as np

from vrsim.common.errors import VehicleError
from vrsim.vehicle.coverage import CoveragePath


def track_arrays(where: str, time_s, **values) -> tuple[np.ndarray, ...]:
    """``time_s`` and each of ``values`` as float arrays of one 1-D shape, time strictly increasing.

    Raises `VehicleError` naming `where` (e.g. ``"Gnss.measure"``) and the arguments otherwise.
    """
    t = np.asarray(time_s, dtype=float)
    arrays = [np.asarray(v, dtype=float) for v in values.values()]
    if not (t.ndim == 1 and len(t) > 0 and all(a.shape == t.shape for a in arrays)):
        names = ", ".join(["time_s", *values])
        shapes = ", ".join(str(a.shape) for a in (t, *arrays))
        raise VehicleError(f"{where}: {names} must be 1-D of one length, got {shapes}")
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        raise VehicleError(f"{where}: time_s must be strictly increasing")
    return (t, *arrays)


def ticks_between(last: tuple, steps: tuple, tick_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ticks from just after SUMO's sample `last` up to its last step in `steps`, interpolated.

    Parameters
    ----------
    last : (time_s, s_m, speed_m_s)
        The sample before `steps` (at rest at s = 0, time 0, before the first step).
    steps : (time_s, s_m, speed_m_s) of arrays
        SUMO's samples, each at a whole number of ticks.
    tick_s : float
        The tick, s.

    Returns
    -------
    time_s, s_m, speed_m_s : ndarray
        One value per tick: the time as a whole number of ticks (the same floats as a drive whose
        SUMO step is the tick), arc length and speed linear in time between SUMO's samples (the
        positions follow from the arc length, on the path: `track_on_path`).
    """
    t0, s0, v0 = last
    t, s, v = steps
    first, end = round(t0 / tick_s) + 1, round(float(t[-1]) / tick_s)
    time_s = np.arange(first, end + 1) * tick_s
    knots = np.concatenate([[t0], t])
    return (time_s, np.interp(time_s, knots, np.concatenate([[s0], s])),
            np.interp(time_s, knots, np.concatenate([[v0], v])))


def track_on_path(path: CoveragePath, time_s, s_m, speed_m_s) -> dict:
    """The per-tick track of a drive from what SUMO reported (`SumoDriver.run_parts`): arc lengths
    clipped to the path, position, heading and segment there, the implement on inside a working
    segment and before the path's end. Per tick, so a drive's parts give the whole's track.

    Returns
    -------
    dict of ndarray, shape (n,)
        ``time_s``, ``s_m``, ``x_m``, ``y_m``, ``heading_rad`` (math convention), ``speed_m_s``,
        ``implement_on`` (bool), ``segment_index`` (int).
    """
    s = np.clip(s_m, 0.0, path.length_m)
    x, y, heading, seg, on = path.locate(s)
    on = on & (s < path.length_m)
    return {"time_s": np.asarray(time_s, float), "s_m": s, "x_m": x, "y_m": y, "heading_rad": heading,
            "speed_m_s": np.asarray(speed_m_s, float), "implement_on": on, "segment_index": seg}
