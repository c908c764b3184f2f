"""Load-cell model: a stiff spring under whatever presses on it.

The cell reads the force pushing down on its platform. That force comes from a settable
``applied_force_n`` or from a callable ``force_source(t_s) -> newtons`` that another model or a
scene installs (a grasped stick pressing on the scale, a scripted press). A strain-gauge cell is a
very stiff spring (~1 mm deflection at full scale), so its platform barely moves; past its rated
capacity the force keeps rising but the bridge output is what the HX711 clamps (the scale mock's
business, not this model's).
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model


class LoadCell:
    """A load cell: ``force_n`` at the last ``advance_to``; ``deflection_mm`` = force / stiffness."""

    def __init__(self, world: Any = None, rng: np.random.Generator | None = None, *,
                 capacity_n: float = 49.0, stiffness_n_per_mm: float = 50.0,
                 applied_force_n: float = 0.0, tare_mass_g: float = 0.0) -> None:
        check_range("capacity_n", capacity_n, 0.01, 1e6, "N")
        check_range("stiffness_n_per_mm", stiffness_n_per_mm, 1e-3, 1e9, "N/mm")
        self.capacity_n = float(capacity_n)
        self.stiffness_n_per_mm = float(stiffness_n_per_mm)
        self.applied_force_n = float(applied_force_n)
        # The platform's own weight: it is what a tare removes.
        self.tare_mass_g = float(tare_mass_g)
        self.force_source: Callable[[float], float] | None = None
        self.force_n = self.applied_force_n
        self.t_s = 0.0

    def set_force_source(self, source: Callable[[float], float] | None) -> None:
        """Make the load come from ``source(t_s)`` (newtons, downward positive); None: the set value."""
        self.force_source = source

    def force_at(self, t_s: float) -> float:
        """Downward force on the platform at ``t_s`` in newtons (NaN from a source counts as 0)."""
        f = self.force_source(t_s) if self.force_source is not None else self.applied_force_n
        f = float(f)
        return f if math.isfinite(f) else 0.0

    def advance_to(self, t_s: float) -> None:
        if t_s >= self.t_s:
            self.t_s = t_s
        self.force_n = self.force_at(self.t_s)

    @property
    def deflection_mm(self) -> float:
        return self.force_n / self.stiffness_n_per_mm


@register_model("load_cell")
def _load_cell(world: Any, rng: np.random.Generator, **params: Any) -> LoadCell:
    """Scene model ``load_cell``: ``capacity_n``, ``stiffness_n_per_mm``, ``applied_force_n``, ``tare_mass_g``."""
    return LoadCell(world, rng, **params)
