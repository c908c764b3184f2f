"""Rigid obstacles for collision scenes: planes the fingertip can press into (model kind "table").

The skin is the compliant part: pressing ``pen`` mm past the surface pushes back with
``stiffness_n_per_mm · pen`` along the surface normal. The arm is position controlled and does not
feel it; only the tactile sensor does (which is why a late stop means overtravel, not a stall).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model


class Table:
    """A plane through ``point_mm`` with outward unit ``normal`` (free space on its side)."""

    def __init__(self, point_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 normal: tuple[float, float, float] = (0.0, 0.0, 1.0),
                 stiffness_n_per_mm: float = 5.0) -> None:
        n = np.asarray(normal, dtype=float)
        norm = float(np.linalg.norm(n))
        if not norm > 0:
            raise ValueError(f"table.normal={normal!r} must be a non-zero vector")
        check_range("table.stiffness_n_per_mm", stiffness_n_per_mm, 1e-3, 1e6, "N/mm")
        self.point_mm = np.asarray(point_mm, dtype=float)
        self.normal = n / norm
        self.stiffness_n_per_mm = float(stiffness_n_per_mm)

    def advance_to(self, t_s: float) -> None:  # static
        return None

    def penetration_mm(self, p_mm: np.ndarray) -> float:
        """How far ``p_mm`` (x, y, z) lies past the surface (0 in free space)."""
        return max(0.0, -float(np.dot(np.asarray(p_mm[:3], dtype=float) - self.point_mm, self.normal)))

    def force_n(self, p_mm: np.ndarray) -> np.ndarray:
        """The push of the surface on a fingertip at ``p_mm`` (N, world axes)."""
        return self.stiffness_n_per_mm * self.penetration_mm(p_mm) * self.normal


@register_model("table")
def _table(world: Any, rng: np.random.Generator, **params: Any) -> Table:
    """Scene model: ``point_mm``, ``normal``, ``stiffness_n_per_mm``."""
    return Table(**params)
