"""A scripted human hand (model kind "hand"): brings an object, presses it, lets go; or moves it.

Handover script (times in seconds from the start of the scene):

* before ``arrive_s`` the object is not between the fingers;
* from ``arrive_s`` the hand holds it between the fingers, carrying its full weight and pressing it
  against one fingertip with ``press_n`` (0: it hovers without touching);
* from ``release_s`` over ``release_duration_s`` the support and the press fall linearly to 0
  (``release_s = inf``: the hand never lets go); meanwhile the hand may move the object down
  through the fingers at ``descend_mps`` (a pass-through without handing over).

Following script: ``path_mm`` is a list of ``[t_s, x_mm, y_mm, z_mm]`` waypoints of the object the
hand moves (linear in between, held at the ends); ``twist_deg`` a list of ``[t_s, theta_deg]``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactile_rig.sim.base import register_model


def _interp(points: list[list[float]], t_s: float) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    return np.array([np.interp(t_s, arr[:, 0], arr[:, i]) for i in range(1, arr.shape[1])])


class Hand:
    """The scripted hand; all methods are pure functions of time."""

    def __init__(self, *, arrive_s: float = 0.0, press_n: float = 0.5, release_s: float = math.inf,
                 release_duration_s: float = 1.0, descend_mps: float = 0.0, leave_s: float = math.inf,
                 path_mm: list[list[float]] | None = None, twist_deg: list[list[float]] | None = None,
                 t0_s: float = 0.0) -> None:
        if release_duration_s <= 0:
            raise ValueError(f"hand.release_duration_s={release_duration_s!r} must be > 0")
        self.t0_s = float(t0_s)  # the scene's start on the clock: script times count from it
        self.arrive_s = self.t0_s + float(arrive_s)
        self.press_n_max = float(press_n)
        self.release_s = self.t0_s + float(release_s)
        self.release_duration_s = float(release_duration_s)
        self.descend_mps = float(descend_mps)
        self.leave_s = self.t0_s + float(leave_s)
        self.path_mm = path_mm
        self.twist_deg = twist_deg

    def advance_to(self, t_s: float) -> None:  # scripted: nothing to integrate
        return None

    def present(self, t_s: float) -> bool:
        """The hand holds the object between the fingers (arrived, not yet gone)."""
        return self.arrive_s <= t_s < self.leave_s

    def holding_frac(self, t_s: float) -> float:
        """Fraction of the object's weight the hand still carries (1 → 0 during the release)."""
        if not self.present(t_s):
            return 0.0
        if t_s <= self.release_s:
            return 1.0
        return max(0.0, 1.0 - (t_s - self.release_s) / self.release_duration_s)

    def press_n(self, t_s: float) -> float:
        """Force pressing the object against one fingertip (N)."""
        return self.press_n_max * self.holding_frac(t_s)

    def descent_mm(self, t_s: float) -> float:
        """How far the hand has moved the object down through the fingers since it arrived."""
        if t_s <= self.arrive_s or self.descend_mps == 0.0:
            return 0.0
        return 1000.0 * self.descend_mps * (min(t_s, self.leave_s) - self.arrive_s)

    def position_mm(self, t_s: float) -> np.ndarray:
        """Where the hand holds the object (x, y, z mm) on the following path."""
        if not self.path_mm:
            return np.zeros(3)
        return _interp(self.path_mm, t_s - self.t0_s)

    def twist_at_deg(self, t_s: float) -> float:
        if not self.twist_deg:
            return 0.0
        return float(_interp(self.twist_deg, t_s - self.t0_s)[0])


@register_model("hand")
def _hand(world: Any, rng: np.random.Generator, **params: Any) -> Hand:
    """Scene model: the :class:`Hand` script parameters."""
    return Hand(t0_s=world.clock.now_s(), **params)
