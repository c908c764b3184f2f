"""Stick assembly (thesis ch. 4) as one scene controller built from the smaller ones.

1. Centre the stick between the fingers (Alg. 5): move across the stick until the fingertip
   camera sees its centroid on the image centre line (proximity vision, within ``centre_tol_px``).
2. Scan for the best grasp (Alg. 6): step along the stick over ``scan_range_mm``, score each
   position by the grasp quality the sensor reports, go back to the best one and grasp.
3. Find the table by collision: a guarded descent (:class:`CollisionStop`, capped speed).
4. Insert until the scale reads the load: press down slowly until the :class:`ForceGauge` reads
   ``target_load_n``, then stop (the overshoot is bounded by the press speed × the scale's period).

The grasp quality is read from ``TouchReading.object_area_px`` normalised by its maximum over the
scan (a square, well-centred contact shows the largest area).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from tactile_rig.control.collision_stop import CollisionStop, CollisionStopParams
from tactile_rig.control.common import (
    ControllerResult,
    Outcome,
    go,
    guarded,
    move_and_wait,
    read_fresh,
)
from tactile_rig.control.protocols import (
    ForceGauge,
    Gripper,
    GripperOutcome,
    Motion,
    Pose,
    TactileSensor,
    Trace,
)
from tactile_rig.core.clock import Clock


@dataclass
class StickAssemblyParams:
    """Parameters (mm, px, N, m/s)."""

    mm_per_px: float = 0.2
    image_centre_y_px: float = 60.0
    centre_tol_px: float = 1.0
    centre_gain: float = 0.8  # fraction of the seen offset corrected per look
    max_centre_steps: int = 20
    scan_range_mm: float = 40.0  # scan ± this along the stick
    scan_step_mm: float = 4.0
    move_speed_mps: float = 0.02
    grasp_m: float = 0.0
    effort: float = 0.5
    descend_mm: float = 80.0  # how far the guarded descent may go
    collision: CollisionStopParams = field(default_factory=lambda: CollisionStopParams(retreat_mm=0.0))
    approach_speed_frac_of_cap: float = 0.9
    target_load_n: float = 5.0
    press_speed_mps: float = 0.0005
    press_limit_mm: float = 5.0  # never press further than this past the contact
    scale_timeout_s: float = 0.5
    frame_timeout_s: float = 0.5


class StickAssembly:
    """The assembly sequence on a Motion, a Gripper, a TactileSensor and a ForceGauge."""

    def __init__(self, motion: Motion, gripper: Gripper, sensor: TactileSensor, scale: ForceGauge,
                 clock: Clock, params: StickAssemblyParams | None = None) -> None:
        self.motion = motion
        self.gripper = gripper
        self.sensor = sensor
        self.scale = scale
        self.clock = clock
        self.p = params or StickAssemblyParams()
        self.trace = Trace()
        self.figures: dict[str, float] = {}
        self._phase = 0

    PHASES = ("centre", "scan", "find_table", "press")

    def step(self) -> str | None:
        """Run the next phase; returns its name, or None when all are done."""
        if self._phase >= len(self.PHASES):
            return None
        name = self.PHASES[self._phase]
        if name == "centre":
            self.figures["centre_offset_px"] = self.centre()
        elif name == "scan":
            self.figures["grasp_x_mm"] = self.scan()
        elif name == "find_table":
            res = self.find_table()
            if res.outcome is Outcome.FAULT:
                raise _Faulted(res)
            if res.outcome is not Outcome.SUCCESS:
                raise _Fail(f"no table found: {res.message}")
            self.figures["table_z_mm"] = res.contact_pose.z_mm if res.contact_pose else math.nan  # type: ignore[attr-defined]
        else:
            self.figures["final_load_n"] = self.press()
        self._phase += 1
        return name

    # -- phases -------------------------------------------------------------------------------------
    def centre(self) -> float:
        """Alg. 5: returns the last seen offset (px)."""
        off = math.inf
        moved_s = self.clock.now_s()
        for _ in range(self.p.max_centre_steps):
            r = read_fresh(self.sensor, self.clock, moved_s, self.p.frame_timeout_s)
            if r.object_centroid_px is None:
                raise _Fail("no stick in view to centre on")
            off = r.object_centroid_px[1] - self.p.image_centre_y_px
            self.trace.append(self.clock.now_s(), phase=1.0, centre_offset_px=off)
            if abs(off) <= self.p.centre_tol_px:
                return off
            q = self.motion.pose()
            dy = self.p.centre_gain * off * self.p.mm_per_px
            move_and_wait(self.motion, self.clock, Pose(q.x_mm, q.y_mm + dy, q.z_mm, q.theta_deg),
                          self.p.move_speed_mps)
            moved_s = self.clock.now_s()
        raise _Fail(f"could not centre the stick ({off:.1f} px off after {self.p.max_centre_steps} moves)")

    def scan(self) -> float:
        """Alg. 6: returns the x (mm) of the best grasp and grasps there."""
        q0 = self.motion.pose()
        n = int(round(2 * self.p.scan_range_mm / self.p.scan_step_mm))
        best_x, best_q = q0.x_mm, -math.inf
        for i in range(n + 1):
            x = q0.x_mm - self.p.scan_range_mm + i * self.p.scan_step_mm
            move_and_wait(self.motion, self.clock, Pose(x, q0.y_mm, q0.z_mm, q0.theta_deg), self.p.move_speed_mps)
            r = read_fresh(self.sensor, self.clock, self.clock.now_s(), self.p.frame_timeout_s)
            self.trace.append(self.clock.now_s(), phase=2.0, x_mm=x, quality=r.object_area_px)
            if r.object_area_px > best_q:
                best_x, best_q = x, r.object_area_px
        move_and_wait(self.motion, self.clock, Pose(best_x, q0.y_mm, q0.z_mm, q0.theta_deg), self.p.move_speed_mps)
        if go(self.gripper, self.p.grasp_m, self.p.effort, blocking=True, timeout_s=3.0) is GripperOutcome.REACHED:
            raise _Fail("the fingers closed on nothing")
        return best_x

    def find_table(self) -> ControllerResult:
        cs = CollisionStop(self.motion, self.sensor, self.clock, self.p.collision)
        cs.calibrate()
        q = self.motion.pose()
        res = cs.run(Pose(q.x_mm, q.y_mm, q.z_mm - self.p.descend_mm, q.theta_deg),
                     self.p.approach_speed_frac_of_cap * cs.cap_mps())
        self.figures["approach_cap_mps"] = cs.cap_mps()
        return res

    def press(self) -> float:
        """Press down until the scale reads the target load; returns the last reading (N)."""
        q = self.motion.pose()
        self.motion.move_toward(Pose(q.x_mm, q.y_mm, q.z_mm - self.p.press_limit_mm, q.theta_deg),
                                self.p.press_speed_mps)
        while True:
            load = self.scale.read_force_n(self.p.scale_timeout_s)
            z = self.motion.pose().z_mm
            self.trace.append(self.clock.now_s(), phase=4.0, load_n=load, z_mm=z)
            if load >= self.p.target_load_n:
                self.motion.stop()
                return load
            if z <= q.z_mm - self.p.press_limit_mm + 1e-3:
                self.motion.stop()
                raise _Fail(f"pressed {self.p.press_limit_mm} mm without reaching {self.p.target_load_n} N")

    # -- run ---------------------------------------------------------------------------------------
    def run(self) -> ControllerResult:
        self.trace = Trace()
        self.figures = {}
        return guarded(self._run, self.trace, motion=self.motion, gripper=self.gripper, gripper_action="hold")

    def _run(self) -> ControllerResult:
        self._phase = 0
        try:
            while self.step() is not None:
                pass
        except _Faulted as f:
            return ControllerResult(Outcome.FAULT, self.trace, self.figures, f.result.message, f.result.fault_device)
        except _Fail as exc:
            self.motion.stop()
            return ControllerResult(Outcome.FAILED, self.trace, self.figures, str(exc))
        return ControllerResult(Outcome.SUCCESS, self.trace, self.figures,
                                f"assembled: {self.figures['final_load_n']:.2f} N on the scale")


class _Fail(Exception):
    pass


class _Faulted(Exception):
    def __init__(self, result: ControllerResult) -> None:
        super().__init__(result.message)
        self.result = result
