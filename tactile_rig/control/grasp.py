"""Leaky-integrator gripper control (thesis eq. 3.3) and the handover on top of it (Alg. 3).

Eq. 3.3, as implemented: the closing amount ``g`` (m, past the reference opening) integrates a
binary drive ``u`` and leaks back:

    g ← clip(g + Δt (gain · u − leak · g), 0, g_max),    opening command y = max(y_min, y_ref − g)

``u = 1`` closes at ``gain`` m/s; with ``leak > 0`` the grip relaxes when nothing drives it, which
finds the least grip that stops slip at the cost of re-tightening on the next slip; ``leak = 0``
(the handover default) holds what it reached.

Handover (Alg. 3): a person holds the object between the open fingers. The drive is
``L = slip ∧ touch``: the gripper closes only while the object slips while touching the skin (the
person lets go), never on a touch alone (the person is still holding) nor on motion without touch
(the object passes by), and stops closing as soon as slip stops; ``y_min`` bounds the squeeze.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactile_rig.control.common import (
    ControllerResult,
    Outcome,
    check_gripper,
    go,
    guarded,
    read_touch,
)
from tactile_rig.control.protocols import Gripper, TactileSensor, TouchReading, Trace
from tactile_rig.core.clock import Clock


class LeakyIntegrator:
    """Eq. 3.3: ``g ← clip(g + dt (gain u − leak g), g_min, g_max)``; units of ``gain``: m/s."""

    def __init__(self, gain_mps: float, leak_per_s: float = 0.0, g_max_m: float = math.inf,
                 g_min_m: float = 0.0) -> None:
        if not gain_mps >= 0:
            raise ValueError(f"gain_mps={gain_mps!r} must be ≥ 0")
        if not leak_per_s >= 0:
            raise ValueError(f"leak_per_s={leak_per_s!r} must be ≥ 0")
        self.gain_mps = float(gain_mps)
        self.leak_per_s = float(leak_per_s)
        self.g_max_m = float(g_max_m)
        self.g_min_m = float(g_min_m)
        self.g_m = 0.0

    def step(self, u: float, dt_s: float) -> float:
        """Integrate drive ``u`` (typically −1, 0 or 1) over ``dt_s``; return ``g`` (m)."""
        if not (dt_s >= 0 and math.isfinite(dt_s)):
            raise ValueError(f"dt_s={dt_s!r} must be a finite time step ≥ 0")
        if not math.isfinite(u):  # NaN would clip to g_min silently: an opening from nowhere
            raise ValueError(f"u={u!r} must be a finite drive (typically −1, 0 or 1)")
        g = self.g_m + dt_s * (self.gain_mps * float(u) - self.leak_per_s * self.g_m)
        self.g_m = min(self.g_max_m, max(self.g_min_m, g))
        return self.g_m


@dataclass
class HandoverParams:
    """Handover parameters (SI units)."""

    open_m: float = 0.04  # y_ref: the opening the hand brings the object into
    y_min_m: float = 0.0  # never command a smaller opening than this
    close_gain_mps: float = 0.08  # integrator gain while L = slip ∧ touch
    leak_per_s: float = 0.0
    effort: float = 0.5  # fraction of the current limit that caps the squeeze
    touch_force_n: float = 0.15  # normal force that counts as touch (sensor force units)
    duration_s: float = 6.0  # the handover window
    settle_s: float = 0.5  # held = touching and no slip during the last settle_s
    frame_timeout_s: float = 0.5


class Handover:
    """Alg. 3 on a :class:`Gripper` and a :class:`TactileSensor`."""

    def __init__(self, gripper: Gripper, sensor: TactileSensor, clock: Clock,
                 params: HandoverParams | None = None) -> None:
        self.gripper = gripper
        self.sensor = sensor
        self.clock = clock
        self.p = params or HandoverParams()
        self.integrator = LeakyIntegrator(self.p.close_gain_mps, self.p.leak_per_s,
                                          g_max_m=max(0.0, self.p.open_m - self.p.y_min_m))
        self.trace = Trace()
        self._last_t: float | None = None
        self._cmd_m: float | None = None
        self.closings = 0

    def drive(self, r: TouchReading) -> bool:
        """L = slip ∧ touch for one reading."""
        touch = r.contact or abs(r.force_n[2]) > self.p.touch_force_n
        return bool(r.slip and touch)

    def step(self) -> TouchReading:
        check_gripper(self.gripper)  # a servo that faulted while holding must end the run
        r = read_touch(self.sensor, self.clock, self.p.frame_timeout_s)
        dt = 0.0 if self._last_t is None else max(0.0, r.t_s - self._last_t)
        self._last_t = r.t_s
        L = self.drive(r)
        g = self.integrator.step(1.0 if L else 0.0, dt)
        y = max(self.p.y_min_m, self.p.open_m - g)
        if self._cmd_m is None or abs(y - self._cmd_m) > 1e-6:
            if self._cmd_m is not None and y < self._cmd_m:
                self.closings += 1
            go(self.gripper, y, self.p.effort, blocking=False)
            self._cmd_m = y
        self.trace.append(self.clock.now_s(), frame_t_s=r.t_s, fz_n=r.force_n[2], slip=float(r.slip),
                          touch=float(r.contact), drive=float(L), g_m=g, command_m=y)
        return r

    def run(self) -> ControllerResult:
        self.trace = Trace()
        return guarded(self._run, self.trace, gripper=self.gripper, gripper_action="hold")

    def _run(self) -> ControllerResult:
        t_end = self.clock.now_s() + self.p.duration_s
        last_slip_t = -math.inf
        touched = held_once = False
        while self.clock.now_s() < t_end:
            r = self.step()
            touch = r.contact or abs(r.force_n[2]) > self.p.touch_force_n
            if r.slip:
                last_slip_t = r.t_s
            if touch:
                touched = True
            if self.integrator.g_m > 0 and touch and r.t_s - last_slip_t >= self.p.settle_s:
                held_once = True
            if held_once and not touch:
                return ControllerResult(Outcome.FAILED, self.trace, self._figures(),
                                        "lost touch after holding: dropped")
        figures = self._figures()
        if not touched:
            return ControllerResult(Outcome.NO_CONTACT, self.trace, figures, "nothing was handed over")
        if self.integrator.g_m == 0:
            return ControllerResult(Outcome.NO_CONTACT, self.trace, figures,
                                    "touched but never slipped: the person kept the object")
        if held_once:
            return ControllerResult(Outcome.SUCCESS, self.trace, figures, "object taken and held")
        return ControllerResult(Outcome.FAILED, self.trace, figures, "still slipping at the end")

    def _figures(self) -> dict[str, float]:
        return {"closed_m": self.integrator.g_m, "closings": float(self.closings),
                "final_command_m": self._cmd_m if self._cmd_m is not None else math.nan}
