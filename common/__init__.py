"""Small things every vrsim package may use: the error hierarchy, number checks and the version.

`maps`, `vehicle` and `controller` never import each other or `services`; what they must share lives
here, and only that.
"""

from vrsim.common.checks import check_number, check_positive, in_range, is_number
from vrsim.common.errors import (
    ClusterError,
    ControllerError,
    MapError,
    ScenarioError,
    ServiceError,
    VehicleError,
    VrsimError,
)

__version__ = "0.1.0"

__all__ = [
    "VrsimError",
    "MapError",
    "VehicleError",
    "ControllerError",
    "ScenarioError",
    "ServiceError",
    "check_number",
    "check_positive",
    "in_range",
    "is_number",
    "ClusterError",
    "__version__",
]
