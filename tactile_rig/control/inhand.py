"""In-hand rotation by allowed slip, and by torque (thesis ch. 3, on the leaky integrator).

A stick held off its centre of mass turns under gravity when the grip loosens. The controller
opens the fingers slowly (the leaky integrator driven with ``u = −1``), lets the object rotate and
re-grips when it reaches the target angle (default 90°: from horizontal to hanging; the thesis
writes π/2 as π).

* ``mode = "slip"``: the angle comes from the sensor's object orientation (FingerVision's
  proximity vision); the re-grip is anticipated by ``lookahead_s`` of the measured angular rate.
* ``mode = "torque"``: the angle is estimated from the torque the skin carries while the object
  is stuck, ``τ = τ₀ cos θ / cos θ₀``. While it slides the torque is the lower kinetic one, which
  makes the estimate run ahead (the re-grip comes early); after each re-grip the controller waits
  for the object to stick, re-estimates, and opens again until the estimate is within tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactile_rig.clock import Clock
from tactile_rig.control.common import ControllerResult, Outcome, guarded, read_touch
from tactile_rig.control.grasp import LeakyIntegrator
from tactile_rig.control.protocols import Gripper, TactileSensor, TouchReading, Trace


@dataclass
class InHandRotationParams:
    """Parameters (SI units; angles in degrees from the start pose's frame of the sensor)."""

    target_deg: float = 90.0  # rotation to reach, measured from the start angle
    mode: str = "slip"  # "slip" (orientation feedback) or "torque" (torque-estimated angle)
    open_rate_mps: float = 0.002  # how fast the fingers open while rotating
    max_open_m: float = 0.004  # never open more than this past the start opening (drop guard)
    regrip_m: float = 0.002  # re-grip this much tighter than the start opening to stop the turn
    effort: float = 0.5
    lookahead_s: float = 0.12  # anticipate the turn by this much of the measured rate (slip mode)
    tolerance_deg: float = 3.0  # torque mode: done when the estimate is this close
    settle_s: float = 0.3  # wait after a re-grip before measuring the final angle
    start_angle_deg: float = 0.0  # the object's angle from horizontal at the start (torque mode)
    slip_limit_mm: float = 8.0  # translational slide allowed before the controller re-grips for good
    duration_s: float = 15.0
    frame_timeout_s: float = 0.5


class InHandRotation:
    """Rotate a held object in the fingers to ``target_deg`` by letting it slip."""

    def __init__(self, gripper: Gripper, sensor: TactileSensor, clock: Clock,
                 params: InHandRotationParams | None = None) -> None:
        if params is not None and params.mode not in ("slip", "torque"):
            raise ValueError(f"mode={params.mode!r} must be 'slip' or 'torque'")
        self.gripper = gripper
        self.sensor = sensor
        self.clock = clock
        self.p = params or InHandRotationParams()
        self.trace = Trace()
        self.integrator = LeakyIntegrator(self.p.open_rate_mps, 0.0, g_max_m=self.p.max_open_m)
        self._angle0: float | None = None
        self._tau0: float | None = None
        self._prev: tuple[float, float] | None = None
        self.rate_dps = 0.0
        self.slid_mm = 0.0

    # -- angle estimates ------------------------------------------------------------------------
    def angle_deg(self, r: TouchReading) -> float:
        """The rotation so far (deg) from this reading, by the configured mode."""
        if self.p.mode == "torque":
            assert self._tau0 is not None
            c0 = math.cos(math.radians(self.p.start_angle_deg))
            ratio = r.torque_nmm[2] / self._tau0 * c0 if self._tau0 else 0.0
            return math.degrees(math.acos(max(-1.0, min(1.0, ratio)))) - self.p.start_angle_deg
        if r.object_orientation_deg is None:
            raise ValueError("the sensor reports no object orientation: use mode='torque'")
        assert self._angle0 is not None
        return float(r.object_orientation_deg) - self._angle0

    def _read(self) -> TouchReading:
        return read_touch(self.sensor, self.clock, self.p.frame_timeout_s)

    def step(self, y_start: float) -> tuple[TouchReading, float]:
        """One frame of opening: returns the reading and the angle estimate."""
        r = self._read()
        ang = self.angle_deg(r)
        if self._prev is not None and r.t_s > self._prev[0]:
            inst = (ang - self._prev[1]) / (r.t_s - self._prev[0])
            self.rate_dps = 0.5 * self.rate_dps + 0.5 * inst
            dt = r.t_s - self._prev[0]
        else:
            dt = 0.0
        self._prev = (r.t_s, ang)
        if r.slip and abs(r.slip_mm) > 0:
            self.slid_mm += abs(r.slip_mm)
        g = self.integrator.step(1.0, dt)  # g: how far past the start opening the fingers are
        self.gripper.gripper_go(y_start + g, self.p.effort, blocking=False)
        self.trace.append(self.clock.now_s(), frame_t_s=r.t_s, angle_deg=ang, rate_dps=self.rate_dps,
                          torque_nmm=r.torque_nmm[2], open_m=g, slip=float(r.slip))
        return r, ang

    # -- run -------------------------------------------------------------------------------------
    def run(self) -> ControllerResult:
        self.trace = Trace()
        return guarded(self._run, self.trace, gripper=self.gripper, gripper_action="hold")

    def _regrip(self, y_start: float) -> None:
        self.gripper.gripper_go(max(0.0, y_start - self.p.regrip_m), self.p.effort, blocking=False)
        self.integrator.g_m = 0.0

    def _settled_angle(self) -> tuple[float, TouchReading]:
        t_end = self.clock.now_s() + self.p.settle_s
        r = self._read()
        while self.clock.now_s() < t_end:
            r = self._read()
        return self.angle_deg(r), r

    def _run(self) -> ControllerResult:
        y_start = self.gripper.state().opening_m
        r0 = self._read()
        if not r0.contact:
            return ControllerResult(Outcome.FAILED, self.trace, {}, "no object in the fingers")
        self._angle0 = float(r0.object_orientation_deg or 0.0)
        self._tau0 = r0.torque_nmm[2]
        if self.p.mode == "torque" and abs(self._tau0) < 1e-6:
            return ControllerResult(Outcome.FAILED, self.trace, {}, "no torque to estimate the angle from")
        t_end = self.clock.now_s() + self.p.duration_s
        target = self.p.target_deg
        regrips = 0
        while self.clock.now_s() < t_end:
            r, ang = self.step(y_start)
            if not r.contact:
                return ControllerResult(Outcome.FAILED, self.trace, self._figures(ang, regrips), "dropped")
            ahead = ang + (max(0.0, self.rate_dps) * self.p.lookahead_s if self.p.mode == "slip" else 0.0)
            if ahead >= target or self.slid_mm > self.p.slip_limit_mm:
                self._regrip(y_start)
                regrips += 1
                ang, r = self._settled_angle()
                self._prev = None
                self.rate_dps = 0.0
                if not r.contact:
                    return ControllerResult(Outcome.FAILED, self.trace, self._figures(ang, regrips), "dropped")
                if self.slid_mm > self.p.slip_limit_mm:
                    return ControllerResult(Outcome.FAILED, self.trace, self._figures(ang, regrips),
                                            f"slid {self.slid_mm:.1f} mm: stopped before a drop")
                if self.p.mode == "slip" or ang >= target - self.p.tolerance_deg:
                    return ControllerResult(Outcome.SUCCESS, self.trace, self._figures(ang, regrips),
                                            f"rotated to {ang:.1f}°")
        self._regrip(y_start)
        return ControllerResult(Outcome.TIMEOUT, self.trace, self._figures(math.nan, regrips),
                                f"target {target}° not reached in {self.p.duration_s} s")

    def _figures(self, ang: float, regrips: int) -> dict[str, float]:
        return {"final_angle_deg": ang, "target_deg": self.p.target_deg, "regrips": float(regrips),
                "slid_mm": self.slid_mm}
