"""Object following by force (thesis eq. 3.1) and by proximity vision (eq. 3.2).

By force: the end effector moves along the shear force the object exerts on the skin,
``v = K_f · R_se · f_shear`` (outside a dead band), so a person can lead the arm by the object.
By proximity vision: it moves to bring the object's centroid back to the image centre,
``v = K_p · R_ie · (c − c₀)``, where ``R_ie`` rotates image axes into end-effector axes (the
camera is mounted at ``image_rotation_deg`` about the optical axis). Both run at the sensor's rate
and command a waypoint ``v · horizon_s`` ahead at speed ``‖v‖`` (capped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactile_rig.control.common import ControllerResult, Outcome, guarded, read_touch
from tactile_rig.control.protocols import (
    Motion,
    Pose,
    TactileSensor,
    TouchReading,
    Trace,
)
from tactile_rig.core.clock import Clock


def rotate_xy(x: float, y: float, angle_deg: float) -> tuple[float, float]:
    """Rotate a planar vector by ``angle_deg`` (counter-clockwise in the target axes)."""
    if not math.isfinite(angle_deg):
        raise ValueError(f"angle_deg={angle_deg!r} must be a finite rotation in degrees")
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return c * x - s * y, s * x + c * y


def _direction(x: float, y: float) -> tuple[float, float, float]:
    """(unit x, unit y, length) of a finite planar vector, without overflow for huge components."""
    m = max(abs(x), abs(y))
    if m == 0.0:
        return 0.0, 0.0, 0.0
    a, b = x / m, y / m
    n = math.hypot(a, b)
    return a / n, b / n, m * n  # m·n may be inf for components near the float limit: still ordered


@dataclass
class FollowingParams:
    """Parameters; ``mode`` "force" (eq. 3.1) or "proximity" (eq. 3.2)."""

    mode: str = "force"
    gain_mmps_per_n: float = 40.0  # K_f: speed per newton of shear
    deadband_n: float = 0.1
    sensor_rotation_deg: float = 0.0  # R_se: sensor axes → end-effector axes
    gain_per_s: float = 4.0  # K_p: speed per mm of centroid offset (mm/s per mm)
    mm_per_px: float = 0.2  # image scale at the object's distance
    image_rotation_deg: float = 0.0  # R_ie: image axes → end-effector axes
    image_centre_px: tuple[float, float] = (80.0, 60.0)  # c₀
    deadband_px: float = 2.0
    max_speed_mps: float = 0.05
    horizon_s: float = 0.1
    replan_frac: float = 0.0  # re-command only when the velocity changes by more than this fraction
    duration_s: float = 10.0
    frame_timeout_s: float = 0.5


class Following:
    """Follow an object with a :class:`Motion` from what a :class:`TactileSensor` sees."""

    def __init__(self, motion: Motion, sensor: TactileSensor, clock: Clock,
                 params: FollowingParams | None = None) -> None:
        p = params or FollowingParams()
        if p.mode not in ("force", "proximity"):
            raise ValueError(f"mode={p.mode!r} must be 'force' or 'proximity'")
        for name in ("sensor_rotation_deg", "image_rotation_deg", "gain_mmps_per_n", "gain_per_s", "mm_per_px",
                     "deadband_n", "deadband_px", "max_speed_mps"):
            v = getattr(p, name)
            if not math.isfinite(v) or (name != "sensor_rotation_deg" and name != "image_rotation_deg" and v < 0):
                raise ValueError(f"following: {name}={v!r} must be finite" +
                                 ("" if name.endswith("rotation_deg") else " and >= 0"))
        self.motion = motion
        self.sensor = sensor
        self.clock = clock
        self.p = p
        self.trace = Trace()
        self._v_cmd: tuple[float, float] | None = None
        self._target: Pose | None = None

    def velocity_mmps(self, r: TouchReading) -> tuple[float, float]:
        """The commanded planar velocity (mm/s, end-effector axes) for one reading.

        Never faster than ``max_speed_mps``; a reading that is not finite (a perception glitch)
        commands a hold, as does nothing in view. Huge readings keep their direction (the law is
        evaluated as a direction times a capped magnitude, so nothing overflows to inf/NaN).
        """
        p = self.p
        if p.mode == "force":
            fx, fy = float(r.force_n[0]), float(r.force_n[1])
            if not (math.isfinite(fx) and math.isfinite(fy)):
                return 0.0, 0.0
            ux, uy, mag = _direction(fx, fy)
            if mag <= p.deadband_n:
                return 0.0, 0.0
            # (mag − deadband) along the force: continuous at the band's edge
            k = p.gain_mmps_per_n
            speed = k * (mag - p.deadband_n) if k > 0 else 0.0  # 0·inf would be NaN
            ux, uy = rotate_xy(ux, uy, p.sensor_rotation_deg)
        else:
            if r.object_centroid_px is None:
                return 0.0, 0.0  # nothing in view: hold still
            dx = float(r.object_centroid_px[0]) - p.image_centre_px[0]
            dy = float(r.object_centroid_px[1]) - p.image_centre_px[1]
            if not (math.isfinite(dx) and math.isfinite(dy)):
                return 0.0, 0.0
            ux, uy, off_px = _direction(dx, dy)
            if off_px <= p.deadband_px:
                return 0.0, 0.0
            k = p.gain_per_s * p.mm_per_px
            speed = k * off_px if k > 0 else 0.0
            ux, uy = rotate_xy(ux, uy, p.image_rotation_deg)
        speed = min(speed, 1000.0 * p.max_speed_mps)
        return speed * ux, speed * uy

    def _needs_replan(self, q: Pose, vx: float, vy: float) -> bool:
        if self._v_cmd is None or self._target is None:
            return True
        dv = math.hypot(vx - self._v_cmd[0], vy - self._v_cmd[1])
        left = math.hypot(self._target.x_mm - q.x_mm, self._target.y_mm - q.y_mm)
        return dv > self.p.replan_frac * math.hypot(*self._v_cmd) + 0.5 or left < 0.5 * math.hypot(vx, vy) * self.p.horizon_s

    def step(self) -> tuple[float, float]:
        r = read_touch(self.sensor, self.clock, self.p.frame_timeout_s)
        vx, vy = self.velocity_mmps(r)
        q = self.motion.pose()
        speed = math.hypot(vx, vy)
        if speed > 0:
            if self._needs_replan(q, vx, vy):
                # re-plan only on a real change: a planner that restarts every frame (GRBL jogs)
                # would spend its time accelerating and never reach the commanded speed
                h = self.p.horizon_s
                self._target = Pose(q.x_mm + vx * h, q.y_mm + vy * h, q.z_mm, q.theta_deg)
                self._v_cmd = (vx, vy)
                self.motion.move_toward(self._target, speed / 1000.0)
        elif self._v_cmd is not None:
            self.motion.stop()
            self._v_cmd = self._target = None
        self.trace.append(self.clock.now_s(), x_mm=q.x_mm, y_mm=q.y_mm, vx_mmps=vx, vy_mmps=vy,
                          fx_n=r.force_n[0], fy_n=r.force_n[1])
        return vx, vy

    def run(self) -> ControllerResult:
        self.trace = Trace()
        self._v_cmd = self._target = None
        return guarded(self._run, self.trace, motion=self.motion)

    def _run(self) -> ControllerResult:
        t_end = self.clock.now_s() + self.p.duration_s
        while self.clock.now_s() < t_end:
            self.step()
        self.motion.stop()
        return ControllerResult(Outcome.SUCCESS, self.trace, {}, f"followed for {self.p.duration_s} s")
