"""What the controllers see of the world: four small protocols, no device classes.

``Gripper``, ``Motion``, ``TactileSensor`` and ``ForceGauge``. Drivers (``tactile_rig.drivers``),
simulated fakes and users' adapters satisfy them structurally without importing this module, so a
controller runs unchanged on the bench and in simulation. The data they exchange (poses, gripper
states, touch readings, traces) are the shared types of :mod:`tactile_rig.core`.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

from tactile_rig.core.geometry import Pose
from tactile_rig.core.types import (
    GripperOutcome,
    GripperState,
    Localization,
    TouchReading,
    Trace,
)

__all__ = [
    "ForceGauge", "Gripper", "GripperOutcome", "GripperState", "Localization", "Motion", "Pose",
    "TactileSensor", "TouchReading", "Trace",
]


@runtime_checkable
class Gripper(Protocol):
    """A parallel gripper: go to an opening with an effort cap; read its state."""

    def gripper_go(
        self, opening_m: float, effort_frac: float, *, blocking: bool = True, timeout_s: float | None = None
    ) -> GripperOutcome:
        """Move the fingertips to ``opening_m`` metres apart with ``effort_frac`` ∈ [0, 1] the
        fraction of the current limit."""
        ...

    def state(self) -> GripperState: ...


@runtime_checkable
class Motion(Protocol):
    """A Cartesian axis or arm: move toward a pose at a speed, read the pose, stop."""

    def move_toward(self, target: Pose, path_speed_mps: float) -> None:
        """Start moving toward ``target`` (non-blocking) at ``path_speed_mps`` along the straight line
        in (x, y, z, θ) with a degree of θ counted as a millimetre, as GRBL's feed counts a rotary
        axis: a translation runs at ``path_speed_mps`` m/s, a pure rotation at ``1000 ×
        path_speed_mps`` deg/s."""
        ...

    def pose(self) -> Pose: ...

    def stop(self) -> None:
        """Stop as fast as the device allows (feed hold); must be safe to call at any time."""
        ...


@runtime_checkable
class TactileSensor(Protocol):
    """A fingertip sensor that turns its newest frame into a perception result."""

    def read(self, timeout_s: float | None = None) -> Any:
        """The newest perception result (e.g. a FingerVision or GelSight result) with its time."""
        ...


@runtime_checkable
class ForceGauge(Protocol):
    """A load reading in newtons (the scale under the assembly fixture)."""

    def read_force_n(self, timeout_s: float | None = None) -> float:
        """The load now, in newtons."""
        ...
