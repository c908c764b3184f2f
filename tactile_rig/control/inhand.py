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

Near hanging (``cos θ < r_patch / r``) a squeeze that holds the weight out-resists gravity's torque:
the object turns only while it slides. A stall at the squeeze floor learnt from slides, short of
the target, therefore drops that floor for one more slide, while the slide budget
(``slip_limit_mm``) still has room for one as large as the largest so far.
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
from tactile_rig.control.grasp import LeakyIntegrator
from tactile_rig.control.protocols import Gripper, TactileSensor, TouchReading, Trace
from tactile_rig.core.clock import Clock


@dataclass
class InHandRotationParams:
    """Parameters (SI units; angles in degrees from the start pose's frame of the sensor)."""

    target_deg: float = 90.0  # rotation to reach, measured from the start angle
    mode: str = "slip"  # "slip" (orientation feedback) or "torque" (torque-estimated angle)
    open_rate_mps: float = 0.0005  # how fast the fingers open while nothing turns
    close_rate_mps: float = 0.005  # how fast they close again when the turn gets too fast
    rate_max_dps: float = 40.0  # above this angular rate, close (tame the stick-slip burst)
    rate_frames: int = 4  # frames the angular rate is measured over
    max_open_m: float = 0.004  # never open more than this past the start opening (drop guard)
    regrip_m: float = 0.002  # re-grip this much tighter than the start opening to stop the turn
    resume_back_m: float = 0.0003  # after a re-grip, open again from this much short of the last turn
    effort: float = 0.5
    squeeze_by: str = "position"  # loosen by "position" (open the fingers) or by "effort" (current cap)
    lookahead_s: float = 0.12  # anticipate the turn by this much of the measured rate (slip mode)
    torque_mode_slip_frames: int = 5  # torque mode: re-grip after this many slipping frames in a row
    tolerance_deg: float = 3.0  # done when the settled angle is this close (else open again)
    stall_s: float = 3.0  # at the squeeze floor with no progress this long: stop where it is
    accept_deg: float = 5.0  # a stalled rotation this close to the target still counts as reached
    settle_s: float = 0.3  # wait after a re-grip before measuring the final angle
    baseline_frames: int = 5  # frames averaged for the start angle, torque and load
    start_angle_deg: float = 0.0  # the object's angle from horizontal at the start (torque mode)
    min_normal_frac_of_load: float = 0.5  # keep the squeeze ≥ this × the object's weight (drop guard)
    slide_floor_margin: float = 1.3  # after a slide, keep the squeeze ≥ this × the squeeze it slid at
    slide_threshold_mm: float = 0.1  # a frame's slide above this: re-grip at once, then carry on
    slip_limit_mm: float = 12.0  # total slide allowed before giving up (keep below the finger length)
    duration_s: float = 30.0
    frame_timeout_s: float = 0.5


class InHandRotation:
    """Rotate a held object in the fingers to ``target_deg`` by letting it slip."""

    def __init__(self, gripper: Gripper, sensor: TactileSensor, clock: Clock,
                 params: InHandRotationParams | None = None) -> None:
        if params is not None and params.mode not in ("slip", "torque"):
            raise ValueError(f"mode={params.mode!r} must be 'slip' or 'torque'")
        if params is not None and params.squeeze_by not in ("position", "effort"):
            raise ValueError(f"squeeze_by={params.squeeze_by!r} must be 'position' or 'effort'")
        self.gripper = gripper
        self.sensor = sensor
        self.clock = clock
        self.p = params or InHandRotationParams()
        self.trace = Trace()
        # g: opening past the start (m); driven in m/s: open slowly, hold while it slips, close if it turns fast
        self.integrator = LeakyIntegrator(1.0, 0.0, g_max_m=self.p.max_open_m, g_min_m=-self.p.regrip_m)
        self._angle0: float | None = None
        self._tau0: float | None = None
        self._recent: list[tuple[float, float]] = []  # (t_s, angle_deg) of the last frames
        self._resume_m = 0.0
        self._load_n = 0.0
        self._slide_floor_n = 0.0
        self._floor_limited = False
        self._slip_run = 0
        self._prev_normal_n = 0.0
        self.rate_dps = 0.0
        self.slid_mm = 0.0
        self.max_slide_mm = 0.0  # the largest single slide so far (one event, until the re-grip held)
        self._slide_event_mm = 0.0
        self.slide_steps = 0  # slides allowed on purpose to turn past the static limit

    # -- angle estimates ------------------------------------------------------------------------
    def angle_deg(self, r: TouchReading) -> float:
        """The rotation so far (deg) from this reading, by the configured mode."""
        if self.p.mode == "torque":
            assert self._tau0 is not None
            c0 = math.cos(math.radians(self.p.start_angle_deg))
            ratio = r.torque_nmm[2] / self._tau0 * c0 if self._tau0 else 0.0
            if not math.isfinite(ratio):  # a torque glitch: unknown angle (as a lost object), not 0°
                return math.nan
            return math.degrees(math.acos(max(-1.0, min(1.0, ratio)))) - self.p.start_angle_deg
        if r.object_orientation_deg is None:  # the object is out of view (lost)
            return math.nan
        assert self._angle0 is not None
        return float(r.object_orientation_deg) - self._angle0

    def _read(self) -> TouchReading:
        return read_touch(self.sensor, self.clock, self.p.frame_timeout_s)

    def step(self, y_start: float) -> tuple[TouchReading, float]:
        """One frame of opening: returns the reading and the angle estimate."""
        check_gripper(self.gripper)
        r = self._read()
        ang = self.angle_deg(r)
        dt = r.t_s - self._recent[-1][0] if self._recent else 0.0
        self._recent = (self._recent + [(r.t_s, ang)])[-self.p.rate_frames:]
        if len(self._recent) >= 2 and self._recent[-1][0] > self._recent[0][0]:
            # a slope over a few frames: one frame's difference is mostly angle noise
            (t0, a0), (t1, a1) = self._recent[0], self._recent[-1]
            self.rate_dps = (a1 - a0) / (t1 - t0)
        else:
            self.rate_dps = 0.0
        self.slid_mm += abs(r.slip_mm)
        floor = max(self.p.min_normal_frac_of_load * self._load_n, self._slide_floor_n)
        self._floor_limited = r.force_n[2] < floor
        if r.force_n[2] < 0.9 * floor:
            u = -self.p.close_rate_mps  # about to lose the object: tighten
        elif r.force_n[2] < floor:
            u = 0.0
        elif self.p.mode == "slip" and self.rate_dps > self.p.rate_max_dps:
            u = -self.p.close_rate_mps
        elif r.slip:
            u = 0.0
        else:
            u = self.p.open_rate_mps
        g = self.integrator.step(u, dt)
        self._command(y_start, g)
        self.trace.append(self.clock.now_s(), frame_t_s=r.t_s, angle_deg=ang, rate_dps=self.rate_dps,
                          torque_nmm=r.torque_nmm[2], fz_n=r.force_n[2], open_m=g, slip=float(r.slip),
                          slide_mm=r.slip_mm)
        return r, ang

    # -- run -------------------------------------------------------------------------------------
    def run(self) -> ControllerResult:
        self.trace = Trace()
        return guarded(self._run, self.trace, gripper=self.gripper, gripper_action="hold")

    def _regrip(self, y_start: float) -> None:
        # remember where it turned: the next opening resumes just short of it, not from the start
        self._resume_m = max(0.0, self.integrator.g_m - self.p.resume_back_m)
        self.integrator.g_m = -self.p.regrip_m
        self._command(y_start, self.integrator.g_m)

    def _resume(self, y_start: float) -> None:
        self.integrator.g_m = self._resume_m
        self._command(y_start, self._resume_m)

    def _command(self, y_start: float, g_m: float) -> None:
        """Loosen the grip by ``g_m`` (m past the start opening; negative re-grips).

        ``squeeze_by = "position"`` opens the fingers by ``g_m``. ``"effort"`` keeps them pressed
        ``regrip_m`` into the object and scales the effort (the servo's current cap, hence the
        squeeze) by ``1 − g_m / max_open_m``: on a servo whose position tick moves the squeeze by
        as much as the object's weight (MX-64 on a stiff skin: ~0.5 N per tick) the current step
        is several times finer, fine enough to rest just above the least holding squeeze.
        """
        if self.p.squeeze_by == "effort":
            effort = min(1.0, max(0.0, self.p.effort * (1.0 - g_m / self.p.max_open_m)))
            go(self.gripper, max(0.0, y_start - self.p.regrip_m), effort, blocking=False)
        else:
            go(self.gripper, max(0.0, y_start + g_m), self.p.effort, blocking=False)

    def _settled_angle(self) -> tuple[float, TouchReading]:
        """After a re-grip: wait ``settle_s``, then average the angle over the second half of it
        (the object is held still; one frame's angle carries the sensor's noise, ~0.5° here)."""
        t_end = self.clock.now_s() + self.p.settle_s
        t_avg = t_end - 0.5 * self.p.settle_s
        r = self._read()
        late: list[float] = []
        while self.clock.now_s() < t_end:
            r = self._read()
            # a slide goes on until the re-grip bites: count it into the budget and the event's size
            self.slid_mm += abs(r.slip_mm)
            self._slide_event_mm += abs(r.slip_mm)
            if r.t_s >= t_avg:
                late.append(self.angle_deg(r))
        late = [a for a in late if math.isfinite(a)]
        return (sum(late) / len(late) if late else self.angle_deg(r)), r

    def _run(self) -> ControllerResult:
        y_start = self.gripper.state().opening_m
        first = [self._read() for _ in range(max(1, self.p.baseline_frames))]
        r0 = first[-1]
        if not r0.contact:
            return ControllerResult(Outcome.FAILED, self.trace, {}, "no object in the fingers")
        if self.p.mode == "slip" and r0.object_orientation_deg is None:
            raise ValueError("the sensor reports no object orientation: use mode='torque'")
        self._angle0 = sum(float(r.object_orientation_deg or 0.0) for r in first) / len(first)
        self._tau0 = sum(r.torque_nmm[2] for r in first) / len(first)
        # while stuck, the two skins carry the weight: twice this one's shear
        self._load_n = 2.0 * sum(math.hypot(r.force_n[0], r.force_n[1]) for r in first) / len(first)
        if self.p.mode == "torque" and abs(self._tau0) < 1e-6:
            return ControllerResult(Outcome.FAILED, self.trace, {}, "no torque to estimate the angle from")
        t_end = self.clock.now_s() + self.p.duration_s
        target = self.p.target_deg
        regrips = 0
        best = (-math.inf, self.clock.now_s())  # (angle, when it was last beaten by 1°)
        while self.clock.now_s() < t_end:
            r, ang = self.step(y_start)
            if ang > best[0] + 1.0:
                best = (ang, self.clock.now_s())
            elif self._floor_limited and self.clock.now_s() - best[1] > self.p.stall_s:
                # the squeeze is at its floor and nothing turns: judge on the settled angle (a frame's
                # estimate near hanging is noisy, by torque more than by orientation)
                self._regrip(y_start)
                ang, r = self._settled_angle()
                self._slide_event_mm = 0.0
                if r.contact and self._may_slide_again(ang, target):
                    # Near hanging, a squeeze that holds the weight (2 μs N ≥ m g) resists more torque
                    # than gravity's m g r cos θ once cos θ < r_patch / r: the object turns further
                    # only while it slides. Drop the learnt floor for one more slide, caught at once
                    # by the re-grip below; that slide re-learns the floor.
                    self._slide_floor_n = 0.0
                    self.slide_steps += 1
                    self._recent = []
                    self.rate_dps = 0.0
                    best = (ang, self.clock.now_s())
                    self._resume(y_start)
                    continue
                ok = r.contact and abs(ang - target) <= self.p.accept_deg
                return ControllerResult(Outcome.SUCCESS if ok else Outcome.FAILED, self.trace,
                                        self._figures(ang, regrips),
                                        f"stalled at {ang:.1f}°: cannot turn further without sliding")
            if not r.contact:
                return ControllerResult(Outcome.FAILED, self.trace, self._figures(ang, regrips), "dropped")
            ahead = ang + (max(0.0, self.rate_dps) * self.p.lookahead_s if self.p.mode == "slip" else 0.0)
            sliding = abs(r.slip_mm) > self.p.slide_threshold_mm
            if sliding:
                self._slide_event_mm += abs(r.slip_mm)
                # it slid at about this squeeze: never open that far again (the learned floor)
                self._slide_floor_n = max(self._slide_floor_n, self.p.slide_floor_margin * self._prev_normal_n)
            self._prev_normal_n = r.force_n[2]
            if self.p.mode == "slip":
                too_fast = self.rate_dps > self.p.rate_max_dps
            else:  # a torque-estimated angle is too noisy to differentiate: a long slip is the cue
                self._slip_run = self._slip_run + 1 if r.slip else 0
                too_fast = self._slip_run >= self.p.torque_mode_slip_frames
            if ahead >= target or sliding or too_fast or self.slid_mm > self.p.slip_limit_mm:
                self._regrip(y_start)
                regrips += 1
                ang, r = self._settled_angle()
                # the whole slide of this event, re-grip included: the size the next allowed slide may take
                self.max_slide_mm = max(self.max_slide_mm, self._slide_event_mm)
                self._slide_event_mm = 0.0
                self._recent = []
                self.rate_dps = 0.0
                if not r.contact:
                    return ControllerResult(Outcome.FAILED, self.trace, self._figures(ang, regrips), "dropped")
                if self.slid_mm > self.p.slip_limit_mm:
                    return ControllerResult(Outcome.FAILED, self.trace, self._figures(ang, regrips),
                                            f"slid {self.slid_mm:.1f} mm: stopped before a drop")
                if ang >= target - self.p.tolerance_deg:
                    return ControllerResult(Outcome.SUCCESS, self.trace, self._figures(ang, regrips),
                                            f"rotated to {ang:.1f}°")
                self._resume(y_start)
        # out of time (slides near hanging gain little each): stop where it is and judge the settled
        # angle as a stall is judged
        self._regrip(y_start)
        ang, r = self._settled_angle()
        if r.contact and abs(ang - target) <= self.p.accept_deg:
            return ControllerResult(Outcome.SUCCESS, self.trace, self._figures(ang, regrips),
                                    f"rotated to {ang:.1f}° when the time ran out")
        return ControllerResult(Outcome.TIMEOUT, self.trace, self._figures(ang, regrips),
                                f"target {target}° not reached in {self.p.duration_s} s (at {ang:.1f}°)")

    def _may_slide_again(self, ang: float, target: float) -> bool:
        """At a stall short of the target: may the learnt squeeze floor be dropped for one more slide?

        Only when a slide floor is what blocks the turn, and one more slide as large as the largest
        so far (with margin) still fits in ``slip_limit_mm``: the slide budget is what prevents a drop.
        """
        if self._slide_floor_n <= 0.0 or ang >= target - self.p.tolerance_deg:
            return False
        return self.slid_mm + self.p.slide_floor_margin * self.max_slide_mm <= self.p.slip_limit_mm

    def _figures(self, ang: float, regrips: int) -> dict[str, float]:
        return {"final_angle_deg": ang, "target_deg": self.p.target_deg, "regrips": float(regrips),
                "slid_mm": self.slid_mm,
                "slide_steps": float(self.slide_steps)}
