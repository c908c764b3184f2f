"""A fingertip closing onto the scale's platform: the live force-map collection on mocks.

Only what that session needs is modelled. The scale stands between the gripper's fingers, its
platform facing the FingerVision fingertip (on the bench: the gripper mounted so that fingertip
closes onto the platform). The fingers close freely until the opening reaches
``contact_opening_m``; beyond it the fingertip skin and the load cell compress together as one
linear spring ``stiffness_npm`` (the skin is by far the softer of the two), so

- the fingers see an object of width ``contact_opening_m`` and stiffness ``stiffness_npm`` (set on
  the ``fingers`` model: the servo stalls where that spring balances its capped current, so the
  session steps the force by stepping the effort);
- the load cell reads ``F = stiffness_npm · (contact_opening_m − opening)`` (N, ≥ 0);
- the fingertip feels ``F`` as its normal force and ``shear_fraction · F`` along its y axis: the
  finger closes on an arc, so the platform also drags the skin tangentially (the FingerVision
  renderer reads ``normal_force_n``, ``shear_x_n``, ``shear_y_n``, ``torque_nmm``).

It is registered as kind ``scale_press`` and is named ``contact`` in the scene so the renderer finds it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model


class ScalePress:
    """Contact state of a fingertip pressing on the scale (see the module doc; forces in N)."""

    def __init__(self, world: Any, rng: np.random.Generator | None = None, *, fingers: str = "fingers",
                 load_cell: str = "load_cell", contact_opening_m: float = 0.03, stiffness_npm: float = 4000.0,
                 shear_fraction: float = 0.25) -> None:
        self.contact_opening_m = check_range("contact_opening_m", float(contact_opening_m), 0.0, 1.0, "m")
        self.stiffness_npm = check_range("stiffness_npm", float(stiffness_npm), 1.0, 1e9, "N/m")
        self.shear_fraction = check_range("shear_fraction", float(shear_fraction), 0.0, 1.0)
        self.fingers = world.require(fingers, who="the scale press")
        self.load_cell = world.require(load_cell, who="the scale press")
        # The platform is the object between the fingers: the servo pushes against this spring.
        self.fingers.object_width_m = self.contact_opening_m
        self.fingers.object_stiffness_npm = self.stiffness_npm
        self.load_cell.set_force_source(self.force_at)
        self.t_s = 0.0

    def force_at(self, t_s: float) -> float:
        """Force on the platform (N) with the fingers where they are (the world advances them first)."""
        return max(0.0, self.stiffness_npm * (self.contact_opening_m - float(self.fingers.opening_m())))

    def advance_to(self, t_s: float) -> None:
        self.t_s = max(self.t_s, float(t_s))

    # -- what the FingerVision renderer reads as the contact --------------------------------------
    @property
    def normal_force_n(self) -> float:
        return self.force_at(self.t_s)

    @property
    def shear_x_n(self) -> float:
        return 0.0

    @property
    def shear_y_n(self) -> float:
        return self.shear_fraction * self.force_at(self.t_s)

    @property
    def torque_nmm(self) -> float:
        return 0.0


register_model("scale_press")(ScalePress)
