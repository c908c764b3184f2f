"""Collision stop (thesis Alg. 2): move, stop on a force change, say where it came from, retreat.

Before moving, the mean force over a few frames is remembered (the skin is never exactly zero);
while moving, a frame whose force differs from that mean by more than ``force_eps_n`` is a
collision: stop, report the direction of the change, back off along the path. The approach speed
is capped (:mod:`tactile_rig.control.safety`) from the measured sensing rate and latency so that
the axis never travels more than ``allowed_overtravel_mm`` past contact; faster commands are
refused with a :class:`~tactile_rig.core.errors.LimitError` before anything moves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactile_rig.control.common import (
    ControllerResult,
    Outcome,
    guarded,
    move_and_wait,
    pose_distance_mm,
    read_touch,
    record_pose,
    vec_norm,
)
from tactile_rig.control.protocols import Motion, Pose, TactileSensor, Trace
from tactile_rig.control.safety import (
    check_speed,
    collision_speed_cap_mps,
    measure_sensing,
)
from tactile_rig.core.clock import Clock

_AXES = ("x", "y", "z")


@dataclass
class CollisionStopParams:
    """Parameters of the collision stop; defaults are the thesis's where it gives them."""

    force_eps_n: float = 0.5  # f_ε: force change that counts as a collision (sensor force units)
    baseline_frames: int = 5  # frames averaged for the force before moving
    allowed_overtravel_mm: float = 1.0  # travel past contact the cap is derived for (thesis: 1 mm)
    sensing_rate_hz: float | None = None  # None: measured from the sensor before moving
    latency_s: float | None = None  # capture → controller; None: measured
    stop_latency_s: float = 0.0  # stop command → the axis starts braking (the Motion's own latency)
    decel_mps2: float = math.inf  # the axis's braking deceleration
    contact_stiffness_n_per_mm: float | None = None  # known skin stiffness: adds f_ε/k to the budget
    retreat_mm: float = 3.0  # how far to back off along the path after a collision
    retreat_speed_mps: float = 0.005
    frame_timeout_s: float = 0.5  # a sensor silent this long is a fault (camera freeze)
    timeout_s: float = 60.0  # budget of one guarded move


@dataclass
class CollisionStopResult(ControllerResult):
    """``direction``: the unit force change at the stop (sensor frame), ``direction_axis`` e.g. "-z"."""

    direction: tuple[float, float, float] | None = None
    direction_axis: str | None = None
    contact_pose: Pose | None = None
    cap_mps: float = math.nan


class CollisionStop:
    """Guarded move of a :class:`Motion` with a :class:`TactileSensor` watching for contact."""

    def __init__(self, motion: Motion, sensor: TactileSensor, clock: Clock,
                 params: CollisionStopParams | None = None) -> None:
        self.motion = motion
        self.sensor = sensor
        self.clock = clock
        self.p = params or CollisionStopParams()
        self.baseline_n: tuple[float, float, float] | None = None
        self.rate_hz = self.p.sensing_rate_hz
        self.latency_s = self.p.latency_s
        self.trace = Trace()

    # -- the cap -------------------------------------------------------------------------------
    def calibrate(self) -> None:
        """Measure the sensing rate/latency (unless given) and the force baseline; the axis is still."""
        if self.rate_hz is None or self.latency_s is None:
            m = measure_sensing(self.sensor, self.clock, n_frames=max(3, self.p.baseline_frames),
                                timeout_s=self.p.frame_timeout_s)
            self.rate_hz = self.rate_hz if self.rate_hz is not None else m.rate_hz
            self.latency_s = self.latency_s if self.latency_s is not None else m.latency_s
        forces = [read_touch(self.sensor, self.clock, self.p.frame_timeout_s).force_n
                  for _ in range(max(1, self.p.baseline_frames))]
        self.baseline_n = tuple(sum(f[i] for f in forces) / len(forces) for i in range(3))  # type: ignore[assignment]

    def cap_mps(self) -> float:
        """The speed cap at the current sensing figures (calibrate first when they are measured)."""
        if self.rate_hz is None or self.latency_s is None:
            raise ValueError("the sensing rate/latency are unknown: call calibrate() or give them")
        det = 0.0
        if self.p.contact_stiffness_n_per_mm:
            det = self.p.force_eps_n / self.p.contact_stiffness_n_per_mm
        return collision_speed_cap_mps(self.p.allowed_overtravel_mm, self.rate_hz, self.latency_s,
                                       stop_latency_s=self.p.stop_latency_s, decel_mps2=self.p.decel_mps2,
                                       detection_travel_mm=det)

    def watchdog_s(self) -> float:
        """How long to wait for a frame while moving: a frame later than one period (plus the
        latency) means the sensor stalled, and every extra moment is blind travel."""
        if self.rate_hz is None or self.latency_s is None:
            return self.p.frame_timeout_s
        return min(self.p.frame_timeout_s, 1.1 / self.rate_hz + self.latency_s)

    # -- the loop --------------------------------------------------------------------------------
    def step(self) -> tuple[bool, tuple[float, float, float]]:
        """One look: (collided, force change). Stops the axis on a collision."""
        assert self.baseline_n is not None
        r = read_touch(self.sensor, self.clock, self.watchdog_s())
        df = tuple(r.force_n[i] - self.baseline_n[i] for i in range(3))
        p = self.motion.pose()
        record_pose(self.trace, self.clock.now_s(), p, fx_n=df[0], fy_n=df[1], fz_n=df[2],
                    frame_t_s=r.t_s)
        hit = vec_norm(df) > self.p.force_eps_n
        if hit:
            self.motion.stop()
        return hit, df  # type: ignore[return-value]

    def run(self, target: Pose, speed_mps: float) -> CollisionStopResult:
        """Move toward ``target`` at ``speed_mps`` until contact (SUCCESS) or arrival (NO_CONTACT).

        Raises :class:`LimitError` before moving when ``speed_mps`` exceeds the cap.
        """
        self.trace = Trace()
        if self.baseline_n is None or self.rate_hz is None or self.latency_s is None:
            res = guarded(self._calibrate_result, self.trace, motion=self.motion)
            if res is not None and res.outcome is Outcome.FAULT:
                return CollisionStopResult(**vars(res))
        cap = self.cap_mps()
        check_speed(speed_mps, cap)
        res = guarded(lambda: self._run(target, speed_mps, cap), self.trace, motion=self.motion)
        if not isinstance(res, CollisionStopResult):
            res = CollisionStopResult(**vars(res), cap_mps=cap)
        return res

    def _calibrate_result(self) -> ControllerResult:
        self.calibrate()
        return ControllerResult(Outcome.SUCCESS, self.trace)

    def _run(self, target: Pose, speed_mps: float, cap: float) -> CollisionStopResult:
        start = self.motion.pose()
        self.motion.move_toward(target, speed_mps)
        t_end = self.clock.now_s() + self.p.timeout_s
        while True:
            hit, df = self.step()
            if hit:
                return self._collided(start, df, speed_mps, cap)
            if pose_distance_mm(self.motion.pose(), target) < 0.01:
                return CollisionStopResult(Outcome.NO_CONTACT, self.trace, {"speed_mps": speed_mps},
                                           "reached the target without contact", cap_mps=cap)
            if self.clock.now_s() > t_end:
                self.motion.stop()
                return CollisionStopResult(Outcome.TIMEOUT, self.trace, {"speed_mps": speed_mps},
                                           f"no contact and target not reached in {self.p.timeout_s} s",
                                           cap_mps=cap)

    def _collided(self, start: Pose, df: tuple[float, float, float], speed_mps: float,
                  cap: float) -> CollisionStopResult:
        contact = self.motion.pose()
        mag = vec_norm(df)
        direction = tuple(v / mag for v in df)
        k = max(range(3), key=lambda i: abs(direction[i]))
        axis = ("+" if direction[k] > 0 else "-") + _AXES[k]
        # Back off along the path we came (not along the force: the path is known to be free).
        travelled = pose_distance_mm(start, contact)
        back = min(self.p.retreat_mm, travelled)
        if travelled > 1e-9 and back > 0:
            f = back / travelled
            retreat = Pose(contact.x_mm + (start.x_mm - contact.x_mm) * f,
                           contact.y_mm + (start.y_mm - contact.y_mm) * f,
                           contact.z_mm + (start.z_mm - contact.z_mm) * f,
                           contact.theta_deg + (start.theta_deg - contact.theta_deg) * f)
            self._settle()
            # no faster than the cap: the retreat is not watched, so it gets the approach's margin
            move_and_wait(self.motion, self.clock, retreat, min(self.p.retreat_speed_mps, cap),
                          timeout_s=self.p.timeout_s, trace=self.trace)
        figures = {"speed_mps": speed_mps, "force_change_n": mag}
        return CollisionStopResult(Outcome.SUCCESS, self.trace, figures, f"collision along {axis}",
                                   direction=direction, direction_axis=axis,  # type: ignore[arg-type]
                                   contact_pose=contact, cap_mps=cap)

    def _settle(self, max_wait_s: float = 2.0) -> None:
        """Wait until the axis has come to rest after the stop (its pose stops changing)."""
        t_end = self.clock.now_s() + max_wait_s
        prev = self.motion.pose()
        while self.clock.now_s() < t_end:
            self.clock.sleep(0.01)
            cur = self.motion.pose()
            if pose_distance_mm(prev, cur) < 1e-4:
                return
            prev = cur
