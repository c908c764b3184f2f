"""Closed-loop tactile controllers; they depend only on the protocols in :mod:`.protocols` and the
shared types of :mod:`tactile_rig.core`."""

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

# Controllers: each a small class with its parameters, ``step()`` and ``run()``.
from tactile_rig.control.collision_stop import CollisionStop, CollisionStopParams  # noqa: E402
from tactile_rig.control.common import ControllerResult, Outcome  # noqa: E402
from tactile_rig.control.following import Following, FollowingParams  # noqa: E402
from tactile_rig.control.grasp import Handover, HandoverParams, LeakyIntegrator  # noqa: E402
from tactile_rig.control.inhand import InHandRotation, InHandRotationParams  # noqa: E402
from tactile_rig.control.insertion import Insertion, InsertionParams  # noqa: E402
from tactile_rig.control.lift_effort import LiftEffortParams, MinimalLiftEffort  # noqa: E402
from tactile_rig.control.protocols import ForceGauge, Localization, TouchReading  # noqa: E402
from tactile_rig.control.rotation import TorqueRotation, TorqueRotationParams  # noqa: E402
from tactile_rig.control.safety import collision_speed_cap_mps  # noqa: E402
from tactile_rig.control.stick_assembly import StickAssembly, StickAssemblyParams  # noqa: E402

__all__ += [
    "CollisionStop", "CollisionStopParams", "ControllerResult", "Outcome", "Following", "FollowingParams",
    "Handover", "HandoverParams", "LeakyIntegrator", "InHandRotation", "InHandRotationParams", "Insertion",
    "InsertionParams", "LiftEffortParams", "MinimalLiftEffort", "ForceGauge", "Localization", "TouchReading",
    "TorqueRotation", "TorqueRotationParams", "collision_speed_cap_mps", "StickAssembly", "StickAssemblyParams",
]
