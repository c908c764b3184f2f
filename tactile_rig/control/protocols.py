"""What the controllers see of the world: three small protocols, no device classes.

Drivers (``tactile_rig.drivers``), mocks and users' adapters satisfy these structurally without
importing this module, so a controller runs unchanged on the bench and in simulation.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable


class GripperOutcome(str, enum.Enum):
    """How a ``gripper_go`` ended."""

    REACHED = "reached"  # within tolerance of the goal opening
    STALLED = "stalled_on_object"  # stopped on an object: current at the effort cap, no progress
    MOVING = "moving"  # non-blocking call: the move was started
    TIMEOUT = "timeout"
    FAULT = "fault"  # a hardware error latched (overload, overheating); torque is off


@dataclass
class GripperState:
    """A snapshot of the gripper, SI units."""

    t_s: float
    opening_m: float  # distance between the fingertips
    opening_frac: float  # 0 = closed calibration point, 1 = open calibration point
    velocity_mps: float  # rate of change of the opening (negative: closing)
    current_a: float  # motor current, signed
    effort_frac: float  # |current| / current limit
    temperature_c: float
    hardware_error: int = 0  # the servo's Hardware Error Status bits (0 = none)
    moving: bool = False
    active: bool = False  # torque enabled through activate()


@runtime_checkable
class Gripper(Protocol):
    """A parallel gripper: go to an opening with an effort cap; read its state."""

    def gripper_go(
        self, position: float, effort: float, *, blocking: bool = True, timeout_s: float | None = None
    ) -> GripperOutcome:
        """Move to ``position`` (metres of opening, or 0-1 with ``normalized`` drivers) with
        ``effort`` ∈ [0, 1] the fraction of the current limit."""
        ...

    def state(self) -> GripperState: ...


@dataclass
class Pose:
    """A planar pose: millimetres and degrees (the jig's x-y-θ, or an arm's end effector)."""

    x_mm: float = 0.0
    y_mm: float = 0.0
    z_mm: float = 0.0
    theta_deg: float = 0.0


@runtime_checkable
class Motion(Protocol):
    """A Cartesian axis or arm: move toward a pose at a speed, read the pose, stop."""

    def move_toward(self, target: Pose, speed_mps: float) -> None:
        """Start moving toward ``target`` at ``speed_mps`` (non-blocking)."""
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


@dataclass
class Trace:
    """Time series recorded by a controller run: ``t_s`` plus named channels of equal length."""

    t_s: list[float] = field(default_factory=list)
    channels: dict[str, list[float]] = field(default_factory=dict)

    def append(self, t_s: float, **values: float) -> None:
        self.t_s.append(float(t_s))
        n = len(self.t_s)
        for k, v in values.items():
            col = self.channels.setdefault(k, [float("nan")] * (n - 1))
            col.append(float(v))
        for col in self.channels.values():
            if len(col) < n:
                col.append(float("nan"))


# -- additions for the closed-loop controllers (issue 7) -----------------------------------------


@dataclass
class TouchReading:
    """A sensor-agnostic view of one tactile frame, what the controllers consume.

    ``force_n`` is (shear x, shear y, normal z) in the sensor frame and ``torque_nmm`` the moments
    about the sensor axes; with an uncalibrated FingerVision they are pixel units instead (the
    thresholds of a controller are then in those units too). ``t_s`` is the capture time on the
    controller's clock.
    """

    t_s: float
    force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque_nmm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    contact: bool = False
    slip: bool = False
    slip_mm: float = 0.0  # object motion relative to the skin since the previous frame
    object_area_px: float = 0.0
    object_centroid_px: tuple[float, float] | None = None
    object_orientation_deg: float | None = None


@dataclass
class Localization:
    """Where the grasped object lies in the sensor's tactile map (a GelSight ``localize`` result).

    ``x_mm``/``y_mm``/``theta_deg``: the object frame in the map (sensor) frame, ``m_T_o``;
    ``confidence`` ∈ [0, 1] (the paper accepts c ≥ 0.98).
    """

    t_s: float
    x_mm: float
    y_mm: float
    theta_deg: float
    confidence: float


@runtime_checkable
class ForceGauge(Protocol):
    """A load reading in newtons (the scale under the assembly fixture)."""

    def read_n(self, timeout_s: float | None = None) -> float: ...
