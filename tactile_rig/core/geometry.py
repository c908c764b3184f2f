"""One pose type and one transform algebra for the whole package (millimetres and degrees).

A :class:`Pose` is x, y, z in mm and θ in degrees about z: the jig's x-y-θ stage, an arm's end
effector, an object in a tactile map. Transforms between frames are homogeneous matrices named
``a_T_b`` (the pose of frame b in frame a): 4×4 in space, 3×3 in the plane, 2×3 affine in the
plane (OpenCV's convention for image warps). :func:`matrix_from_pose`, :func:`pose_from_matrix` and
:func:`invert_rigid` work on all three shapes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np


@dataclass(frozen=True)
class Pose:
    """A pose: millimetres and degrees (θ about z, counter-clockwise in a right-handed x-y frame;
    in image axes, x right and y down, the same numbers turn clockwise on screen)."""

    x_mm: float = 0.0
    y_mm: float = 0.0
    z_mm: float = 0.0
    theta_deg: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return {"x_mm": float(self.x_mm), "y_mm": float(self.y_mm), "z_mm": float(self.z_mm),
                "theta_deg": float(self.theta_deg)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> "Pose | None":
        """The pose of a dict written by :meth:`as_dict` (``z_mm`` may be absent: planar records)."""
        if d is None:
            return None
        return cls(x_mm=float(d["x_mm"]), y_mm=float(d["y_mm"]), z_mm=float(d.get("z_mm", 0.0)),
                   theta_deg=float(d["theta_deg"]))

    def planar(self) -> tuple[float, float, float]:
        """(x mm, y mm, θ deg)."""
        return (float(self.x_mm), float(self.y_mm), float(self.theta_deg))


def wrap_deg(angle_deg: Any) -> Any:
    """Angle(s) wrapped into (−180, 180] degrees; a float for a scalar, an array for an array."""
    a = np.asarray(angle_deg, dtype=float)
    w = 180.0 - np.mod(180.0 - a, 360.0)
    return float(w) if w.ndim == 0 else w


def rotation_2d(theta_deg: float) -> np.ndarray:
    """The 2×2 rotation by ``theta_deg``."""
    t = math.radians(theta_deg)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s], [s, c]])


def matrix_from_pose(pose: Pose, shape: tuple[int, int] = (4, 4)) -> np.ndarray:
    """The transform of ``pose`` (rotation θ about z, then translation) as a 4×4, 3×3 or 2×3 matrix."""
    r = rotation_2d(pose.theta_deg)
    if shape == (4, 4):
        m = np.eye(4)
        m[:2, :2] = r
        m[:3, 3] = (pose.x_mm, pose.y_mm, pose.z_mm)
        return m
    if shape in ((3, 3), (2, 3)):
        m = np.eye(3)
        m[:2, :2] = r
        m[:2, 2] = (pose.x_mm, pose.y_mm)
        return m[: shape[0]]
    raise ValueError(f"shape {shape} must be (4, 4), (3, 3) or (2, 3)")


def pose_from_matrix(m: np.ndarray) -> Pose:
    """The pose of a rigid transform whose rotation is about z (4×4, 3×3 or 2×3); θ in (−180, 180]."""
    a = np.asarray(m, dtype=float)
    if a.shape not in ((4, 4), (3, 3), (2, 3)) or not np.all(np.isfinite(a)):
        raise ValueError(f"expected a finite 4x4, 3x3 or 2x3 transform, got shape {a.shape}")
    theta = wrap_deg(math.degrees(math.atan2(a[1, 0], a[0, 0])))
    if a.shape == (4, 4):
        return Pose(float(a[0, 3]), float(a[1, 3]), float(a[2, 3]), theta)
    return Pose(float(a[0, 2]), float(a[1, 2]), 0.0, theta)


def invert_rigid(m: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (or affine) transform, 4×4, 3×3 or 2×3, in the same shape: ``[R⁻¹, −R⁻¹t]``.

    The linear block is inverted exactly rather than transposed, so a registration's slightly
    non-orthonormal estimate round-trips too."""
    a = np.asarray(m, dtype=float)
    if a.shape not in ((4, 4), (3, 3), (2, 3)):
        raise ValueError(f"expected a 4x4, 3x3 or 2x3 transform, got shape {a.shape}")
    n = 3 if a.shape == (4, 4) else 2
    r_inv = np.linalg.inv(a[:n, :n])
    out = np.eye(n + 1)
    out[:n, :n] = r_inv
    out[:n, n] = -r_inv @ a[:n, n]
    return out[: a.shape[0]]


def compose(*transforms: np.ndarray) -> np.ndarray:
    """The product ``T1 @ T2 @ ...`` of square homogeneous transforms of one size (``a_T_b @ b_T_c``)."""
    if not transforms:
        raise ValueError("compose needs at least one transform")
    out = np.asarray(transforms[0], dtype=float)
    for t in transforms[1:]:
        out = out @ np.asarray(t, dtype=float)
    return out


def pitch_xy_mm(mm_per_px: float | tuple[float, float] | Sequence[float]) -> tuple[float, float]:
    """A pixel pitch given as one number (square pixels) or as (x, y), in mm per pixel, as (x, y)."""
    if isinstance(mm_per_px, (int, float, np.floating, np.integer)):
        return float(mm_per_px), float(mm_per_px)
    sx, sy = mm_per_px
    return float(sx), float(sy)
