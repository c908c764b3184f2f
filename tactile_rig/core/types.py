"""Data types every layer shares: what a gripper reports, what a tactile frame means to a controller,
where a grasped object lies, and a controller's recorded trace. Plain dataclasses, units in names.

Drivers return them, fakes and mocks produce them, controllers consume them; none of them carries
behaviour that would tie a layer to another.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


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


@dataclass(frozen=True)
class RawFrame:
    """What a source returns: the image in ``channel_order`` and the device's own timestamp/counter."""

    image: np.ndarray
    t_device_s: float | None = None
    device_seq: int | None = None
