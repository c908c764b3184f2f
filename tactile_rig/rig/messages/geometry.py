"""Small conversions shared by the 3-D messages: rotations about z as quaternions, and image pixels to
the sensor frame.

The sensor frame of a fingertip camera (frame id: the camera's name) is the optical frame of ROS
REP 103: origin at the image centre on the undeformed skin, x along the image columns (right), y along
the rows (down), z from the camera through the skin towards the object; lengths in mm.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactile_rig.rig.messages.base import foxglove_messages

__all__ = ["quaternion_z", "pose", "pixels_to_sensor_mm", "FLIP_X"]

FLIP_X = (1.0, 0.0, 0.0, 0.0)  # (x, y, z, w): 180 deg about x, a downward-looking sensor over the stage


def quaternion_z(theta_deg: float) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of a rotation by ``theta_deg`` about z."""
    half = math.radians(float(theta_deg)) / 2.0
    return (0.0, 0.0, math.sin(half), math.cos(half))


def pose(x: float = 0.0, y: float = 0.0, z: float = 0.0,
         q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)) -> Any:
    """A ``foxglove.messages.Pose`` at (x, y, z) with orientation ``q`` (x, y, z, w)."""
    fm = foxglove_messages()
    return fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=float(z)),
                   orientation=fm.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def pixels_to_sensor_mm(points_px: np.ndarray, image_size_px: tuple[int, int], mm_per_px: float) -> np.ndarray:
    """Image points (N x 2, x right and y down, px) as sensor-frame x, y (mm) about the image centre."""
    w, h = image_size_px
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    return (np.asarray(points_px, float).reshape(-1, 2) - centre) * float(mm_per_px)
