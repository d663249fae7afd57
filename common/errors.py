"""One exception base for everything a user can get wrong.

The CLI turns a `VrsimError` into one line on stderr and exit code 2; the Zenoh services turn it into
an error reply ``{"error": message}``. Any other exception is a bug (exit code 1). Messages name the
file, the key or argument, and the offending value, so the user can fix the input without reading code.
"""


class VrsimError(Exception):
    """Bad input or an unusable environment: the user can fix it."""


class MapError(VrsimError):
    """A prescription map that cannot be read, written or looked up."""


class VehicleError(VrsimError):
    """A field, path, machine or SUMO set-up that cannot be driven."""


class ControllerError(VrsimError):
    """Plant or controller parameters that make no sense."""


class ScenarioError(VrsimError):
    """A scenario file with a missing, unknown or out-of-range key."""


class ServiceError(VrsimError):
    """A Zenoh service that cannot be reached or answered badly."""


class ClusterError(VrsimError):
    """A Dask scheduler that does not answer, or a cluster without workers."""
