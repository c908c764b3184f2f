"""A stick for the assembly scene (thesis ch. 4, model kind "stick").

It lies across the open fingers at ``lateral_offset_mm`` from their centre line (the fingertip
camera sees its centroid off the image centre); along its length the grasp quality (how square
and stable the skin contact is) peaks at ``best_grasp_mm`` with width ``quality_width_mm``. Once
grasped, its tip hangs ``tip_below_mm`` under the fingers; the fixture under it (a table at
``table_z_mm``, on the scale) pushes back with ``stiffness_n_per_mm`` per mm of press.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactile_rig.sim.base import register_model


class Stick:
    def __init__(self, *, lateral_offset_mm: float = 0.0, best_grasp_mm: float = 0.0,
                 quality_width_mm: float = 15.0, tip_below_mm: float = 60.0, table_z_mm: float = -30.0,
                 stiffness_n_per_mm: float = 10.0) -> None:
        self.lateral_offset_mm = float(lateral_offset_mm)
        self.best_grasp_mm = float(best_grasp_mm)
        self.quality_width_mm = float(quality_width_mm)
        self.tip_below_mm = float(tip_below_mm)
        self.table_z_mm = float(table_z_mm)
        self.stiffness_n_per_mm = float(stiffness_n_per_mm)

    def advance_to(self, t_s: float) -> None:  # static
        return None

    def lateral_error_mm(self, p: np.ndarray) -> float:
        """Stick centre line minus the fingers' centre (mm), with the arm at ``p``."""
        return self.lateral_offset_mm - float(p[1])

    def quality(self, p: np.ndarray) -> float:
        """Grasp quality ∈ (0, 1] at the arm's position along the stick."""
        d = (float(p[0]) - self.best_grasp_mm) / self.quality_width_mm
        return math.exp(-0.5 * d * d)

    def press_mm(self, p: np.ndarray) -> float:
        """How far the tip presses into the fixture with the arm at ``p``."""
        return max(0.0, self.table_z_mm - (float(p[2]) - self.tip_below_mm))

    def load_n(self, p: np.ndarray) -> float:
        return self.stiffness_n_per_mm * self.press_mm(p)


@register_model("stick")
def _stick(world: Any, rng: np.random.Generator, *, gripper: str | None = "gripper", width_m: float = 0.012,
           **params: Any) -> Stick:
    """Scene model: the :class:`Stick` parameters; it lies between the fingers of ``gripper``."""
    g = world.get(gripper) if gripper else None
    if g is not None and hasattr(g, "set_width_fn"):
        g.set_width_fn(lambda t: width_m)
    return Stick(**params)
