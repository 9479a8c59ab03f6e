"""The core of shared contracts that every layer of fourwis imports and that imports no layer:
the Estimate, Command and SensorReading types, the sensor channel layout, the Estimator and
Controller protocols, the input checks, physical constants and the compiled-kernel plumbing."""

from fourwis.core.checks import (
    check_command,
    check_controller,
    check_estimate,
    check_estimator,
    check_step,
    check_vehicle_params,
    import_factory,
    is_integer,
    is_number,
    member_rows,
)
from fourwis.core.constants import GRAVITY
from fourwis.core.types import (
    CHANNELS,
    N_CHANNELS,
    Command,
    Controller,
    Estimate,
    Estimator,
    SensorReading,
    net_wheel_torque,
)

__all__ = [
    "CHANNELS",
    "GRAVITY",
    "N_CHANNELS",
    "Command",
    "Controller",
    "Estimate",
    "Estimator",
    "SensorReading",
    "check_command",
    "check_controller",
    "check_estimate",
    "check_estimator",
    "check_step",
    "check_vehicle_params",
    "import_factory",
    "is_integer",
    "is_number",
    "member_rows",
    "net_wheel_torque",
]
