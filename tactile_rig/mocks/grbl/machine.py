"""The machine GRBL drives on the jig: its settings, its coordinates, its switches and its probe.

:func:`default_settings` are the jig's ``$`` settings (±20 mm in x/y on 2 mm leadscrews, θ ±180° on a
4:1 belt). :class:`Machine` maps machine positions (GRBL's step counters, in mm, or degrees on the θ
channel) to the stage's physical frame and back: the limit switches sit where the stage's travel
ends, on whole motor steps from its zero; a position is pressing a switch when it is past one; the
probe closes when the stage model says the stage touches. Mixed into
:class:`~tactile_rig.mocks.grbl.firmware.GrblMock`, whose state it uses.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tactile_rig.mocks.grbl.host import GrblHost
from tactile_rig.mocks.grbl.planner import Limits, round_half_away

if TYPE_CHECKING:
    from tactile_rig.sim.world.stage import Stage

__all__ = ["Machine", "default_settings"]


def default_settings(axes: int = 3, theta_axis: str = "Z") -> dict[int, float]:
    """The jig's settings: ±20 mm in x/y on 2 mm leadscrews, θ ±180° on a 4:1 belt."""
    s: dict[int, float] = {0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
                           20: 1, 21: 1, 22: 1, 23: 0, 24: 100.0, 25: 1200.0, 26: 250, 27: 1.0,
                           30: 1000.0, 31: 0.0, 32: 0}
    xy = (1600.0, 1200.0, 100.0, 40.0)  # steps/mm (200×16 / 2 mm), mm/min, mm/s², travel mm
    theta = (35.556, 3600.0, 360.0, 360.0)  # steps/deg (200×16×4/360), deg/min, deg/s², deg
    lift = (400.0, 300.0, 10.0, 20.0)  # an unused Z on grblHAL
    per_axis = [xy, xy, theta if theta_axis == "Z" else lift]
    if axes == 4:
        per_axis.append(theta)
    for i, (steps, rate, acc, travel) in enumerate(per_axis):
        s[100 + i], s[110 + i], s[120 + i], s[130 + i] = steps, rate, acc, travel
    return s


class Machine(GrblHost):
    """Machine ↔ stage geometry of the GRBL mock (a mixin of ``GrblMock``)."""

    if TYPE_CHECKING:
        stage: Stage
        _stage_axes: dict[int, int]  # GRBL axis -> stage pose index

    def _travel(self) -> np.ndarray:
        return np.array([self.settings[130 + i] for i in range(self.n_axes)], float)

    def _limits(self) -> Limits:
        return Limits(np.array([self.settings[100 + i] for i in range(self.n_axes)], float),
                      np.array([self.settings[110 + i] for i in range(self.n_axes)], float),
                      np.array([self.settings[120 + i] for i in range(self.n_axes)], float),
                      float(self.settings[11]))

    def _switch_positions(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = -self._travel() / 2.0, self._travel() / 2.0
        ranges = (self.stage.x_range_mm, self.stage.y_range_mm, self.stage.theta_range_deg)
        for axis, k in self._stage_axes.items():
            lo[axis], hi[axis] = ranges[k]
        steps = self._steps()
        return np.round(lo * steps) / steps, np.round(hi * steps) / steps

    def _phys_from_stage(self) -> np.ndarray:
        p = np.zeros(self.n_axes)
        pose = self.stage.pose()
        for axis, k in self._stage_axes.items():
            p[axis] = pose[k]
        return p

    def phys(self, pos: np.ndarray | None = None) -> np.ndarray:
        """Physical position (the stage's frame) of a machine position (default: the current one)."""
        return self.origin + (self.pos if pos is None else pos)

    def _steps(self) -> np.ndarray:
        return np.array([self.settings[100 + i] for i in range(self.n_axes)], float)

    def _quantize(self, p: np.ndarray) -> np.ndarray:
        s = self._steps()
        return np.array([round_half_away(v * k) for v, k in zip(p, s)]) / s

    def _pressed(self, pos: np.ndarray | None = None) -> list[int]:
        ph = self.phys(pos)
        return [i for i in range(self.n_axes) if ph[i] > self.phys_hi[i] + 1e-9 or ph[i] < self.phys_lo[i] - 1e-9]

    def _probe_closed(self, pos: np.ndarray | None = None, *, away: bool = False) -> bool:
        ph = self.phys(pos)
        touching = self.stage.probe_touching(float(ph[0]), float(ph[1]), float(ph[self.theta_index]))
        return (touching != bool(self.settings[6])) != away

    def _write_stage(self, t_s: float) -> None:
        ph = self.phys()
        self.stage.set_pose(float(ph[0]), float(ph[1]), float(ph[self.theta_index]), t_s)

    @property
    def wco(self) -> np.ndarray:
        return self.gc.wco(2)
