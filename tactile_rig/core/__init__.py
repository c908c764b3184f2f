"""The shared vocabulary every layer may import: errors, clocks, geometry and data types.

Nothing in :mod:`tactile_rig.core` imports another part of the package.
"""

from tactile_rig.core.clock import Clock, Deadline, RealClock, VirtualClock, utc_now
from tactile_rig.core.errors import (
    BenchError,
    CalibrationError,
    CommandRejected,
    ConnectErrors,
    ControlReadbackError,
    DeviceFault,
    DeviceTimeout,
    FrozenStream,
    GrblAlarm,
    GrblError,
    GrblReset,
    LimitError,
    LinkCorrupt,
    NotConnected,
    RigError,
    RunConflict,
    check_range,
)
from tactile_rig.core.geometry import (
    Pose,
    compose,
    invert_rigid,
    matrix_from_pose,
    pose_from_matrix,
    wrap_deg,
)
from tactile_rig.core.types import (
    GripperOutcome,
    GripperState,
    Localization,
    RawFrame,
    TouchReading,
    Trace,
)

__all__ = [
    "BenchError", "CalibrationError", "Clock", "CommandRejected", "ConnectErrors", "ControlReadbackError",
    "Deadline", "DeviceFault", "DeviceTimeout", "FrozenStream", "GrblAlarm", "GrblError", "GrblReset",
    "GripperOutcome", "GripperState", "LimitError", "LinkCorrupt", "Localization", "NotConnected", "Pose",
    "RawFrame", "RealClock", "RigError", "RunConflict", "TouchReading", "Trace", "VirtualClock",
    "check_range", "compose", "invert_rigid", "matrix_from_pose", "pose_from_matrix", "utc_now", "wrap_deg",
]
