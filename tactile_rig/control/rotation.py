"""Torque-driven rotation of the arm: turn until the skin torque τ crosses its threshold.

The arm turns the held object about the tool axis toward ``target`` (e.g. a cap onto a thread or a
key into its slot); when the torque the skin feels departs from its value before turning by more
than ``torque_eps_nmm``, the object met its stop: the arm stops. Like the collision stop, the turn
rate is capped from the sensing rate and latency so the turn past the stop stays within
``allowed_overturn_deg`` (a feed rate in °/s is handled as mm/s: 1° ≡ 1 mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactile_rig.control.common import ControllerResult, Outcome, guarded, read_touch
from tactile_rig.control.protocols import Motion, Pose, TactileSensor, Trace
from tactile_rig.control.safety import check_speed, collision_speed_cap_mps
from tactile_rig.core.clock import Clock


@dataclass
class TorqueRotationParams:
    """Parameters (N·mm, degrees, Hz, s)."""

    torque_eps_nmm: float = 5.0
    baseline_frames: int = 5
    allowed_overturn_deg: float = 2.0
    sensing_rate_hz: float = 30.0
    latency_s: float = 0.0
    stop_latency_s: float = 0.0
    decel_dps2: float = math.inf  # the θ axis's braking deceleration (°/s²)
    torsion_stiffness_nmm_per_deg: float | None = None  # known: adds ε/k to the overturn budget
    frame_timeout_s: float = 0.5
    timeout_s: float = 60.0


class TorqueRotation:
    """Rotate ``motion`` about its θ axis until the torque crosses the threshold."""

    def __init__(self, motion: Motion, sensor: TactileSensor, clock: Clock,
                 params: TorqueRotationParams | None = None) -> None:
        self.motion = motion
        self.sensor = sensor
        self.clock = clock
        self.p = params or TorqueRotationParams()
        self.trace = Trace()
        self.tau0_nmm = 0.0

    def cap_dps(self) -> float:
        """Largest turn rate (°/s) that keeps the overturn within the allowance."""
        det = self.p.torque_eps_nmm / self.p.torsion_stiffness_nmm_per_deg if self.p.torsion_stiffness_nmm_per_deg else 0.0
        return 1000.0 * collision_speed_cap_mps(self.p.allowed_overturn_deg, self.p.sensing_rate_hz,
                                                self.p.latency_s, stop_latency_s=self.p.stop_latency_s,
                                                decel_mps2=self.p.decel_dps2 / 1000.0, detection_travel_mm=det)

    def step(self) -> bool:
        r = read_touch(self.sensor, self.clock, self.p.frame_timeout_s)
        d = r.torque_nmm[2] - self.tau0_nmm
        q = self.motion.pose()
        self.trace.append(self.clock.now_s(), theta_deg=q.theta_deg, dtau_nmm=d)
        if abs(d) > self.p.torque_eps_nmm:
            self.motion.stop()
            return True
        return False

    def run(self, target_theta_deg: float, rate_dps: float) -> ControllerResult:
        """Turn toward ``target_theta_deg`` at ``rate_dps``; refuses a rate above :meth:`cap_dps`."""
        check_speed(rate_dps / 1000.0, self.cap_dps() / 1000.0, who="torque_rotation")
        self.trace = Trace()
        return guarded(lambda: self._run(target_theta_deg, rate_dps), self.trace, motion=self.motion)

    def _run(self, target: float, rate_dps: float) -> ControllerResult:
        taus = [read_touch(self.sensor, self.clock, self.p.frame_timeout_s).torque_nmm[2]
                for _ in range(max(1, self.p.baseline_frames))]
        self.tau0_nmm = sum(taus) / len(taus)
        q = self.motion.pose()
        self.motion.move_toward(Pose(q.x_mm, q.y_mm, q.z_mm, target), rate_dps / 1000.0)
        t_end = self.clock.now_s() + self.p.timeout_s
        while self.clock.now_s() < t_end:
            if self.step():
                th = self.motion.pose().theta_deg
                return ControllerResult(Outcome.SUCCESS, self.trace, {"stop_theta_deg": th},
                                        f"torque threshold crossed at θ = {th:.2f}°")
            if abs(self.motion.pose().theta_deg - target) < 1e-3:
                return ControllerResult(Outcome.NO_CONTACT, self.trace, {}, "reached the target angle freely")
        self.motion.stop()
        return ControllerResult(Outcome.TIMEOUT, self.trace, {}, f"no stop within {self.p.timeout_s} s")
