"""A rotational stop for the held object (model kind "torsion_stop"): free to turn up to
``free_play_deg``, then a torsion spring of ``stiffness_nmm_per_deg`` (a cap meeting its thread's
end, a key in its slot). The skin feels the spring's torque."""

from __future__ import annotations

from typing import Any

import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model


class TorsionStop:
    def __init__(self, *, free_play_deg: float = 30.0, stiffness_nmm_per_deg: float = 20.0) -> None:
        check_range("torsion_stop.stiffness_nmm_per_deg", stiffness_nmm_per_deg, 1e-3, 1e6, "N·mm/°")
        self.free_play_deg = float(free_play_deg)
        self.stiffness_nmm_per_deg = float(stiffness_nmm_per_deg)

    def advance_to(self, t_s: float) -> None:  # static
        return None

    def overturn_deg(self, theta_deg: float) -> float:
        return max(0.0, theta_deg - self.free_play_deg)

    def torque_nmm(self, theta_deg: float) -> float:
        """Torque on the skin when the tool is at ``theta_deg`` (turning positive)."""
        return -self.stiffness_nmm_per_deg * self.overturn_deg(theta_deg)


@register_model("torsion_stop")
def _torsion_stop(world: Any, rng: np.random.Generator, **params: Any) -> TorsionStop:
    return TorsionStop(**params)
