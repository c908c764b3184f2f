"""The x-y-θ jig's stage: where the object under the sensor is, in mm and degrees.

The GRBL mock integrates the motion (planner, acceleration, holds, limits) and writes the pose
here (the mock's machine position plus the origin its homing found). Renderers call
``advance_to(t_s)`` and read ``x_mm``, ``y_mm``, ``theta_deg``. A stage with no controller attached
holds still (or is set by a test with :meth:`Stage.set_pose`). Pose convention: see
:mod:`tactile_rig.sim.world.objects`.

The travel ranges are where the stage's limit switches close (GRBL homes onto the upper ones).
A touch probe rides on the stage (GRBL's probe input, for ``G38.2``-``G38.5``): it is closed while
the pose lies in one of ``probe_boxes_mm`` (``[x_lo, x_hi, y_lo, y_hi]`` each, any θ), or wherever
a function given to :meth:`Stage.set_probe_contact` says so.
"""

from __future__ import annotations

from typing import Any, Callable, Protocol, Sequence

import numpy as np

from tactile_rig.core.errors import LimitError
from tactile_rig.sim.base import register_model


class StageDriver(Protocol):
    """Whatever moves the stage (the GRBL mock): integrates itself up to ``t_s``, writing the pose."""

    def advance_to(self, t_s: float) -> None: ...


class Stage:
    """A motorised x-y-θ stage with travel ranges (mm, mm, degrees)."""

    def __init__(self, world: Any = None, rng: np.random.Generator | None = None, *,
                 x_range_mm: tuple[float, float] | list[float] = (-20.0, 20.0),
                 y_range_mm: tuple[float, float] | list[float] = (-20.0, 20.0),
                 theta_range_deg: tuple[float, float] | list[float] = (-180.0, 180.0),
                 x_mm: float = 0.0, y_mm: float = 0.0, theta_deg: float = 0.0,
                 probe_boxes_mm: Sequence[Sequence[float]] = ()) -> None:
        self.x_range_mm = (float(x_range_mm[0]), float(x_range_mm[1]))
        self.y_range_mm = (float(y_range_mm[0]), float(y_range_mm[1]))
        self.theta_range_deg = (float(theta_range_deg[0]), float(theta_range_deg[1]))
        for name, (lo, hi) in (("x_range_mm", self.x_range_mm), ("y_range_mm", self.y_range_mm),
                               ("theta_range_deg", self.theta_range_deg)):
            if not lo < hi:
                raise ValueError(f"stage {name}={[lo, hi]!r} must be [low, high] with low < high")
        self.x_mm, self.y_mm, self.theta_deg = float(x_mm), float(y_mm), float(theta_deg)
        self.t_s = 0.0
        self.driver: StageDriver | None = None
        self._in_advance = False
        self.probe_boxes_mm: list[tuple[float, float, float, float]] = []
        for box in probe_boxes_mm:
            if len(box) != 4 or not (float(box[0]) < float(box[1]) and float(box[2]) < float(box[3])):
                raise ValueError(f"stage probe box {list(box)!r} must be [x_lo, x_hi, y_lo, y_hi] mm with lo < hi")
            self.probe_boxes_mm.append((float(box[0]), float(box[1]), float(box[2]), float(box[3])))
        self._contact: Callable[[float, float, float], bool] | None = None

    def attach(self, driver: StageDriver | None) -> None:
        """Let ``driver`` (the GRBL mock) move this stage; it is advanced whenever the stage is."""
        self.driver = driver

    def set_pose(self, x_mm: float, y_mm: float, theta_deg: float, t_s: float | None = None) -> None:
        """Put the stage at a pose (the GRBL mock calls this as it integrates; tests may too)."""
        self.x_mm, self.y_mm, self.theta_deg = float(x_mm), float(y_mm), float(theta_deg)
        if t_s is not None and t_s > self.t_s:
            self.t_s = t_s

    def pose(self) -> tuple[float, float, float]:
        return self.x_mm, self.y_mm, self.theta_deg

    def check_reachable(self, x_mm: float, y_mm: float, theta_deg: float) -> None:
        """Raise LimitError if the pose lies outside the travel ranges."""
        for name, v, (lo, hi), unit in (("x_mm", x_mm, self.x_range_mm, "mm"), ("y_mm", y_mm, self.y_range_mm, "mm"),
                                        ("theta_deg", theta_deg, self.theta_range_deg, "deg")):
            if not lo <= v <= hi:
                raise LimitError(f"{name}={v!r} {unit} is outside the stage travel [{lo}, {hi}] {unit}", device="stage")

    def set_probe_contact(self, contact: Callable[[float, float, float], bool] | None) -> None:
        """Let ``contact(x_mm, y_mm, theta_deg)`` decide when the probe touches (None: the boxes only)."""
        self._contact = contact

    def probe_touching(self, x_mm: float, y_mm: float, theta_deg: float) -> bool:
        """Whether the probe is in contact at this pose (its switch closed)."""
        if self._contact is not None and self._contact(x_mm, y_mm, theta_deg):
            return True
        return any(x0 <= x_mm <= x1 and y0 <= y_mm <= y1 for x0, x1, y0, y1 in self.probe_boxes_mm)

    def advance_to(self, t_s: float) -> None:
        if self.driver is not None and not self._in_advance:
            self._in_advance = True  # the driver writes back through set_pose: no recursion
            try:
                self.driver.advance_to(t_s)
            finally:
                self._in_advance = False
        if t_s > self.t_s:
            self.t_s = t_s


@register_model("stage")
def _stage(world: Any, rng: np.random.Generator, **params: Any) -> Stage:
    """Scene model ``stage``: ``x_range_mm``, ``y_range_mm``, ``theta_range_deg``, initial ``x_mm`` …,
    ``probe_boxes_mm`` (where the touch probe closes)."""
    return Stage(world, rng, **params)
