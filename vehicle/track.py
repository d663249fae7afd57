"""Validation of a whole per-tick track, shared by the sensors' vectorized `measure` forms."""

from __future__ import annotations

import numpy as np

from common.errors import VehicleError


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
