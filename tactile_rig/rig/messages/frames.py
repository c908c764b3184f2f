"""The 3-D frames of a bench as ``foxglove.FrameTransforms`` (mm, quaternions), and poses as
``foxglove.PoseInFrame``.

Frames: ``world`` is the jig's work coordinates (x, y, z up, mm); ``jig_stage`` is the stage, moved
by the jig's x, y and turned by θ about z; ``part`` is the part fixed on the stage (identity); each
fingertip camera's sensor frame (frame id: the camera's name, an optical frame, see
:mod:`~tactile_rig.rig.messages.geometry`) sits at the work origin looking down at the stage, as a
jig accuracy bench is set up. Every jig pose message carries all of them, so a viewer that joins late
has the whole tree at once.
"""

from __future__ import annotations

from typing import Any, Iterable

from tactile_rig.rig.messages.base import SchemaDef, foxglove_messages, foxglove_schema, timestamp
from tactile_rig.rig.messages.geometry import FLIP_X, pose, quaternion_z

__all__ = ["WORLD", "STAGE", "PART", "jig_transforms", "pose_in_frame", "moves"]

WORLD = "world"
STAGE = "jig_stage"
PART = "part"


def moves(parent: str, child: str) -> bool:
    """True for the one transform that changes during a session (``world -> jig_stage``); the others
    are fixed (ROS: ``/tf_static``)."""
    return (parent, child) == (WORLD, STAGE)


def _transform(stamp: Any, parent: str, child: str, xyz: tuple[float, float, float],
               q: tuple[float, float, float, float]) -> Any:
    fm = foxglove_messages()
    return fm.FrameTransform(timestamp=stamp, parent_frame_id=parent, child_frame_id=child,
                             translation=fm.Vector3(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
                             rotation=fm.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def jig_transforms(x_mm: float, y_mm: float, z_mm: float, theta_deg: float, log_time_ns: int,
                   sensors: Iterable[str] = ()) -> tuple[SchemaDef, bytes]:
    """``world -> jig_stage`` at the jig's pose, ``jig_stage -> part`` and ``world -> <sensor>`` for
    each sensor frame in ``sensors``."""
    fm = foxglove_messages()
    stamp = timestamp(log_time_ns)
    tfs = [_transform(stamp, WORLD, STAGE, (x_mm, y_mm, z_mm), quaternion_z(theta_deg)),
           _transform(stamp, STAGE, PART, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]
    tfs += [_transform(stamp, WORLD, s, (0.0, 0.0, 0.0), FLIP_X) for s in sorted(set(sensors))]
    return foxglove_schema("FrameTransforms"), fm.FrameTransforms(transforms=tfs).encode()


def pose_in_frame(frame_id: str, x_mm: float, y_mm: float, theta_deg: float, log_time_ns: int,
                  z_mm: float = 0.0) -> tuple[SchemaDef, bytes]:
    """A planar pose (mm, deg about z) in ``frame_id`` as a PoseInFrame."""
    fm = foxglove_messages()
    msg = fm.PoseInFrame(timestamp=timestamp(log_time_ns), frame_id=frame_id,
                         pose=pose(x_mm, y_mm, z_mm, quaternion_z(theta_deg)))
    return foxglove_schema("PoseInFrame"), msg.encode()
