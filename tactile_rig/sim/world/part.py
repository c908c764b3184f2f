"""A rigid part held by the gripper or resting where it was let go (model kind "grasped_part").

For insertion scenes. While the gripper squeezes it, the part moves with the gripper (its pose in
the gripper, ``g_T_o``, fixed at the grasp); open, it stays put in the base frame. Only part of its
length carries features a tactile map can register (``feature_half_length_mm`` about its origin,
along its x axis): a grasp whose skin centre falls outside is not localizable (low confidence).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactile_rig.core.geometry import (
    Pose,
    invert_rigid,
    matrix_from_pose,
    pose_from_matrix,
)
from tactile_rig.sim.base import register_model


class GraspedPart:
    """The part; ``b_T_o`` is its pose in the base frame (4×4, mm)."""

    def __init__(self, world: Any, *, grasp_offset_mm: float = 0.0, grasp_y_mm: float = 0.0,
                 grasp_theta_deg: float = 0.0, width_m: float = 0.012, feature_half_length_mm: float = 8.0,
                 hold_force_n: float = 0.5, gripper: str = "gripper", arm: str = "arm") -> None:
        self.gripper = world.require(gripper, who="grasped_part")
        self.arm = world.require(arm, who="grasped_part")
        self.width_m = float(width_m)
        self.feature_half_length_mm = float(feature_half_length_mm)
        self.hold_force_n = float(hold_force_n)
        self._t = world.clock.now_s()
        # where the part sits in the gripper frame: along the fingers' x by the grasp offset
        self.g_T_o = invert_rigid(matrix_from_pose(Pose(grasp_offset_mm, grasp_y_mm, 0.0, grasp_theta_deg)))
        self.b_T_o = self._b_T_g(self._t) @ self.g_T_o
        self.attached = True
        self.grasps = 1
        if hasattr(self.gripper, "set_width_fn"):
            self.gripper.set_width_fn(lambda t: self.width_m)

    def _b_T_g(self, t_s: float) -> np.ndarray:
        p = self.arm.position_at(t_s)
        return matrix_from_pose(Pose(*map(float, p[:4])))

    def advance_to(self, t_s: float) -> None:
        if t_s <= self._t:
            return
        self.gripper.advance_to(t_s)
        # walk the gripper's history so a release and re-grasp between two looks is not missed
        for t, (_opening, squeeze, _v) in self.gripper.history.between(self._t, t_s):
            held = squeeze > self.hold_force_n
            if self.attached and not held:
                self.b_T_o = self._b_T_g(t) @ self.g_T_o  # let go here
                self.attached = False
            elif not self.attached and held:
                self.g_T_o = invert_rigid(self._b_T_g(t)) @ self.b_T_o  # grasped again, wherever it lies
                self.attached = True
                self.grasps += 1
        if self.attached:
            self.b_T_o = self._b_T_g(t_s) @ self.g_T_o
        self._t = t_s

    def pose_mm_deg(self, t_s: float | None = None) -> tuple[float, float, float, float]:
        """(x, y, z mm, θ deg) of the part in the base frame."""
        self.advance_to(self._t if t_s is None else t_s)
        p = pose_from_matrix(self.b_T_o)
        return p.x_mm, p.y_mm, p.z_mm, p.theta_deg

    def skin_centre_in_part_mm(self) -> float:
        """Where along the part's x axis the fingertips' centre lies (mm from the part origin)."""
        return float(invert_rigid(self.g_T_o)[0, 3]) if self.attached else math.nan

    def g_T_o_at(self, t_s: float) -> np.ndarray:
        self.advance_to(max(t_s, self._t))
        return self.g_T_o.copy()


@register_model("grasped_part")
def _grasped_part(world: Any, rng: np.random.Generator, **params: Any) -> GraspedPart:
    """Scene model: ``grasp_offset_mm``, ``grasp_y_mm``, ``grasp_theta_deg``, ``feature_half_length_mm``."""
    return GraspedPart(world, **params)
