"""Insertion with a localized grasp (Li et al. 2014): transform chain, regrasp search, velocity law.

Frames: ``b`` robot base, ``g`` gripper, ``m`` the tactile sensor's map, ``o`` the object
(connector). The sensor localizes the object in its map (``m_T_o``, with a confidence ``c``); the
sensor's mounting ``g_T_m`` is known. To put the object at the goal ``b_T_o*`` the gripper must go to

    b_T_g* = b_T_o* · (m_T_o)⁻¹ · (g_T_m)⁻¹

If the grasp cannot be localized (``c < 0.98``: the skin touches a featureless part of the object)
the controller regrasps blind: open, slide 0.75 cm forward along the object, close, look again;
then 1.5 cm back; until localized or the search list is exhausted. Motion toward ``q*`` follows
the velocity law ``v* = s* (q* − q) / ‖q* − q‖`` (constant speed ``s*`` along the error).

Poses are planar rigid transforms plus height: (x, y, z mm, θ deg about z), as 4×4 matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from tactile_rig.control.common import (
    ControllerResult,
    Outcome,
    go,
    guarded,
    move_and_wait,
    pose_vec,
)
from tactile_rig.control.protocols import (
    Gripper,
    GripperOutcome,
    Localization,
    Motion,
    Pose,
    TactileSensor,
    Trace,
)
from tactile_rig.core.clock import Clock
from tactile_rig.core.errors import DeviceTimeout
from tactile_rig.core.geometry import (
    compose,
    invert_rigid,
    matrix_from_pose,
    pose_from_matrix,
)


def gripper_goal(b_T_o_goal: Pose, m_T_o: Pose, g_T_m: Pose) -> Pose:
    """``b_T_g* = b_T_o* (m_T_o)⁻¹ (g_T_m)⁻¹``: where the gripper must be to put the object at the goal."""
    return pose_from_matrix(compose(matrix_from_pose(b_T_o_goal), invert_rigid(matrix_from_pose(m_T_o)),
                                    invert_rigid(matrix_from_pose(g_T_m))))


def velocity_command(q: Pose, q_goal: Pose, speed: float) -> tuple[float, float, float, float]:
    """``v* = s* (q* − q)/‖q* − q‖`` in (mm, mm, mm, deg) per second for ``speed`` in mm/s; 0 at the goal.

    The command's norm is exactly ``speed`` (or 0) for any finite poses, however far apart (the
    difference is taken in scaled units, so it neither overflows nor loses its direction); a
    non-finite pose or speed is a ``ValueError``.
    """
    if not (math.isfinite(speed) and speed >= 0):
        raise ValueError(f"speed={speed!r} must be a finite speed >= 0 mm/s")
    a, b = pose_vec(q), pose_vec(q_goal)
    if not all(math.isfinite(v) for v in (*a, *b)):
        raise ValueError(f"velocity_command: poses must be finite, got q={q} and q_goal={q_goal}")
    scale = max(1.0, *(abs(v) for v in (*a, *b)))
    e = [y / scale - x / scale for x, y in zip(a, b)]
    n = math.sqrt(sum(x * x for x in e))
    if n * scale < 1e-12:
        return (0.0, 0.0, 0.0, 0.0)
    return tuple(speed * x / n for x in e)  # type: ignore[return-value]


@dataclass
class InsertionParams:
    """Parameters (mm, degrees, m/s)."""

    hole: Pose = field(default_factory=Pose)  # b_T_o*: the object's pose fully inserted
    sensor_mount: Pose = field(default_factory=Pose)  # g_T_m
    approach_height_mm: float = 10.0  # align this far above the hole, then descend
    min_confidence: float = 0.98  # c at which a localization is trusted (the paper's)
    localize_frames: int = 3  # frames averaged per localization
    search_moves_mm: tuple[float, ...] = (7.5, -15.0)  # regrasp slides along the object, in turn
    speed_mps: float = 0.02  # s*
    insert_speed_mps: float = 0.005
    control_period_s: float = 0.02  # how often the velocity law is re-evaluated
    horizon_s: float = 0.1  # the waypoint lies v*·horizon ahead (clipped at the goal)
    tol_mm: float = 0.05
    open_m: float = 0.04
    close_m: float = 0.0
    effort: float = 0.5
    frame_timeout_s: float = 0.5
    move_timeout_s: float = 30.0


class Insertion:
    """Localize the grasp (regrasping blind if needed), then servo the object into the hole."""

    def __init__(self, motion: Motion, gripper: Gripper, sensor: TactileSensor, clock: Clock,
                 params: InsertionParams | None = None) -> None:
        self.motion = motion
        self.gripper = gripper
        self.sensor = sensor
        self.clock = clock
        self.p = params or InsertionParams()
        self.trace = Trace()
        self.regrasps = 0
        self._fresh_after_s = -math.inf

    # -- pieces ------------------------------------------------------------------------------------
    def localize(self) -> Localization | None:
        """Average a few localizations; None when the confidence is below ``min_confidence``."""
        locs: list[Localization] = []
        while len(locs) < max(1, self.p.localize_frames):
            r = self.sensor.read(self.p.frame_timeout_s)
            if r is None:
                raise DeviceTimeout("no localization", device=getattr(self.sensor, "name", "sensor"))
            if r.t_s < self._fresh_after_s:
                continue  # captured before the last regrasp finished: it shows the old grasp
            locs.append(r)
        c = min(float(loc.confidence) for loc in locs)
        self.trace.append(self.clock.now_s(), confidence=c)
        if c < self.p.min_confidence:
            return None
        n = len(locs)
        return Localization(locs[-1].t_s, sum(loc.x_mm for loc in locs) / n, sum(loc.y_mm for loc in locs) / n,
                            sum(loc.theta_deg for loc in locs) / n, c)

    def regrasp(self, slide_mm: float) -> None:
        """Open, slide the gripper ``slide_mm`` along its own x axis (the object's axis), close."""
        go(self.gripper, self.p.open_m, self.p.effort, blocking=True, timeout_s=3.0)
        q = self.motion.pose()
        th = math.radians(q.theta_deg)
        goal = Pose(q.x_mm + slide_mm * math.cos(th), q.y_mm + slide_mm * math.sin(th), q.z_mm, q.theta_deg)
        move_and_wait(self.motion, self.clock, goal, self.p.speed_mps, timeout_s=self.p.move_timeout_s)
        out = go(self.gripper, self.p.close_m, self.p.effort, blocking=True, timeout_s=3.0)
        if out is GripperOutcome.REACHED:
            raise _Lost("the fingers closed on nothing while regrasping")
        self.regrasps += 1
        self._fresh_after_s = self.clock.now_s()

    def servo_to(self, goal: Pose, speed_mps: float) -> Pose:
        """Follow ``v* = s*(q*−q)/‖q*−q‖`` to ``goal``; returns the pose reached."""
        s = 1000.0 * speed_mps
        t_end = self.clock.now_s() + self.p.move_timeout_s
        while True:
            q = self.motion.pose()
            v = velocity_command(q, goal, s)
            err = math.dist(pose_vec(q), pose_vec(goal))
            self.trace.append(self.clock.now_s(), x_mm=q.x_mm, y_mm=q.y_mm, z_mm=q.z_mm, theta_deg=q.theta_deg,
                              err_mm=err, vx_mmps=v[0], vy_mmps=v[1], vz_mmps=v[2])
            if err <= self.p.tol_mm:
                return q
            if self.clock.now_s() > t_end:
                self.motion.stop()
                raise DeviceTimeout(f"did not reach {goal} in {self.p.move_timeout_s} s",
                                    device=getattr(self.motion, "name", "motion"))
            step = min(1.0, s * self.p.horizon_s / err)
            way = Pose(*[a + step * (b - a) for a, b in zip(pose_vec(q), pose_vec(goal))])
            self.step(way, speed_mps)

    def step(self, waypoint: Pose, speed_mps: float) -> None:
        """One control period: command the next waypoint and wait a period."""
        self.motion.move_toward(waypoint, speed_mps)
        self.clock.sleep(self.p.control_period_s)

    # -- run ----------------------------------------------------------------------------------------
    def run(self) -> ControllerResult:
        self.trace = Trace()
        self.regrasps = 0
        return guarded(self._run, self.trace, motion=self.motion, gripper=self.gripper, gripper_action="hold")

    def _run(self) -> ControllerResult:
        try:
            loc = self.localize()
            moves = list(self.p.search_moves_mm)
            while loc is None and moves:
                self.regrasp(moves.pop(0))
                loc = self.localize()
        except _Lost as exc:
            return ControllerResult(Outcome.FAILED, self.trace, self._figures(None), str(exc))
        if loc is None:
            return ControllerResult(Outcome.FAILED, self.trace, self._figures(None),
                                    f"not localized (c < {self.p.min_confidence}) after {self.regrasps} regrasps")
        m_T_o = Pose(loc.x_mm, loc.y_mm, 0.0, loc.theta_deg)
        goal = gripper_goal(self.p.hole, m_T_o, self.p.sensor_mount)
        above = Pose(goal.x_mm, goal.y_mm, goal.z_mm + self.p.approach_height_mm, goal.theta_deg)
        self.servo_to(above, self.p.speed_mps)
        final = self.servo_to(goal, self.p.insert_speed_mps)
        return ControllerResult(Outcome.SUCCESS, self.trace, self._figures(loc),
                                f"inserted at {final} (c = {loc.confidence:.3f})")

    def _figures(self, loc: Localization | None) -> dict[str, float]:
        return {"regrasps": float(self.regrasps), "confidence": loc.confidence if loc else math.nan}


class _Lost(Exception):
    pass
