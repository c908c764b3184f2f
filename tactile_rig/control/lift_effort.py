"""Minimal lifting effort (thesis Alg. 4): the least grip effort that lifts an object without slip.

Each trial closes with an effort (fraction of the current limit), lifts by ``lift_mm``, watches the
skin for slip, puts the object back and opens. The search halves the effort from a safe start
until a lift slips, then bisects (geometrically) between the slipping and the holding effort until
their ratio is within ``ratio_tol``; the answer is the holding end, so it is never below what held.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactile_rig.control.common import (
    ControllerResult,
    Outcome,
    go,
    guarded,
    move_and_wait,
    read_touch,
)
from tactile_rig.control.protocols import (
    Gripper,
    GripperOutcome,
    Motion,
    Pose,
    TactileSensor,
    Trace,
)
from tactile_rig.core.clock import Clock


@dataclass
class LiftEffortParams:
    """Parameters (SI units; efforts are fractions of the gripper's current limit)."""

    effort_start: float = 0.6  # a safe effort that is expected to hold
    effort_floor: float = 0.002  # the least effort tried (the object weighs next to nothing)
    ratio_tol: float = 1.05  # stop when holding/slipping efforts are within this ratio
    lift_mm: float = 8.0
    lift_speed_mps: float = 0.01
    slip_tol_mm: float = 0.3  # total slide during a lift that counts as a slip
    close_m: float = 0.0  # opening commanded to squeeze (well inside the object: effort-limited)
    open_m: float = 0.04  # opening to release the object between trials
    max_trials: int = 25
    frame_timeout_s: float = 0.5


class MinimalLiftEffort:
    """Alg. 4 on a :class:`Gripper`, a :class:`Motion` (lifting) and a :class:`TactileSensor`."""

    def __init__(self, gripper: Gripper, motion: Motion, sensor: TactileSensor, clock: Clock,
                 params: LiftEffortParams | None = None) -> None:
        self.gripper = gripper
        self.motion = motion
        self.sensor = sensor
        self.clock = clock
        self.p = params or LiftEffortParams()
        self.trace = Trace()
        self.trials: list[tuple[float, bool, float]] = []  # (effort, slipped, slide_mm)

    def step(self, effort: float) -> bool:
        """One lift trial at ``effort``; True when the object slipped."""
        out = go(self.gripper, self.p.close_m, effort, blocking=True, timeout_s=3.0)
        if out is GripperOutcome.REACHED:
            raise _NoObject()
        start = self.motion.pose()
        top = Pose(start.x_mm, start.y_mm, start.z_mm + self.p.lift_mm, start.theta_deg)
        self.motion.move_toward(top, self.p.lift_speed_mps)
        slide = 0.0
        t_end = self.clock.now_s() + 2.0 * self.p.lift_mm / (1000.0 * self.p.lift_speed_mps) + 2.0
        while True:
            r = read_touch(self.sensor, self.clock, self.p.frame_timeout_s)
            slide += abs(r.slip_mm)
            p = self.motion.pose()
            self.trace.append(self.clock.now_s(), effort=effort, z_mm=p.z_mm, slide_mm=slide,
                              fz_n=r.force_n[2])
            if slide > self.p.slip_tol_mm or abs(p.z_mm - top.z_mm) < 0.01 or self.clock.now_s() > t_end:
                break
        slipped = slide > self.p.slip_tol_mm
        move_and_wait(self.motion, self.clock, start, self.p.lift_speed_mps, timeout_s=10.0)
        go(self.gripper, self.p.open_m, effort, blocking=True, timeout_s=3.0)
        self.trials.append((effort, slipped, slide))
        return slipped

    def run(self) -> ControllerResult:
        self.trace = Trace()
        self.trials = []
        return guarded(self._run, self.trace, motion=self.motion, gripper=self.gripper, gripper_action="hold")

    def _run(self) -> ControllerResult:
        hi = self.p.effort_start
        try:
            if self.step(hi):
                return self._result(Outcome.FAILED, math.nan, f"slips even at effort {hi}")
            lo = None
            while lo is None:
                if hi <= self.p.effort_floor:
                    return self._result(Outcome.SUCCESS, hi, "holds at the floor effort")
                e = max(hi / 2.0, self.p.effort_floor)
                if self.step(e):
                    lo = e
                else:
                    hi = e
                if len(self.trials) >= self.p.max_trials:
                    return self._result(Outcome.TIMEOUT, hi, "trial budget used up")
            while hi / lo > self.p.ratio_tol:
                e = math.sqrt(hi * lo)
                if self.step(e):
                    lo = e
                else:
                    hi = e
                if len(self.trials) >= self.p.max_trials:
                    return self._result(Outcome.TIMEOUT, hi, "trial budget used up")
        except _NoObject:
            return self._result(Outcome.FAILED, math.nan, "the fingers closed on nothing")
        return self._result(Outcome.SUCCESS, hi, f"minimal effort {hi:.4f} after {len(self.trials)} lifts")

    def _result(self, outcome: Outcome, effort: float, msg: str) -> ControllerResult:
        return ControllerResult(outcome, self.trace, {"effort": effort, "lifts": float(len(self.trials))}, msg)


class _NoObject(Exception):
    pass
