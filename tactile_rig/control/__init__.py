"""Closed-loop tactile controllers; they depend only on the protocols in :mod:`.protocols`."""

from tactile_rig.control.protocols import (
    Gripper,
    GripperOutcome,
    GripperState,
    Motion,
    Pose,
    TactileSensor,
    Trace,
)

__all__ = ["Gripper", "GripperOutcome", "GripperState", "Motion", "Pose", "TactileSensor", "Trace"]
