"""A simulated arm or Cartesian axis that implements the controllers' ``Motion`` protocol.

The end effector's pose is the 4-vector (x, y, z mm, θ deg); as on a GRBL jig, a speed applies to
the Euclidean distance in that space (1° counts as 1 mm). What makes it more than an ideal
integrator:

* command latency: ``move_toward`` and ``stop`` take effect ``command_latency_s`` after the call
  (bus, planner and servo loop of a real arm);
* tracking error: the velocity follows the command through a first-order lag ``tracking_tau_s`` and
  an acceleration limit, so the arm lags its command and overshoots nothing but brakes over
  ``v²/(2·decel)``;
* faults: from ``fault_at_s`` on, the arm latches a protective stop (brakes by itself) and every
  call but ``stop`` raises :class:`~tactile_rig.core.errors.DeviceFault` naming ``arm``.

Model kind ``"arm"``.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.core.deprecation import renamed_kwargs
from tactile_rig.core.errors import DeviceFault, check_range
from tactile_rig.core.geometry import Pose
from tactile_rig.sim.base import register_model
from tactile_rig.sim.world.timeline import Timeline


def _norm(v: np.ndarray) -> float:
    return math.hypot(*v)  # ~10x faster than np.linalg.norm on a 4-vector


class SimArm:
    """A simulated arm on ``clock``; satisfies :class:`tactile_rig.control.protocols.Motion`."""

    name = "arm"

    def __init__(self, clock: Clock, *, start: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
                 command_latency_s: float = 0.005, tracking_tau_s: float = 0.005,
                 accel_mps2: float = 2.0, decel_mps2: float = 5.0, max_speed_mps: float = 0.5,
                 dt_s: float = 0.001, fault_at_s: float | None = None, fault_code: int = 1) -> None:
        check_range("arm.command_latency_s", command_latency_s, 0.0, 1.0, "s")
        check_range("arm.tracking_tau_s", tracking_tau_s, 0.0, 1.0, "s")
        check_range("arm.accel_mps2", accel_mps2, 1e-3, 1e3, "m/s²")
        check_range("arm.decel_mps2", decel_mps2, 1e-3, 1e3, "m/s²")
        check_range("arm.max_speed_mps", max_speed_mps, 1e-4, 10.0, "m/s")
        self.clock = clock
        self.command_latency_s = float(command_latency_s)
        self.tracking_tau_s = float(tracking_tau_s)
        self.accel_mmps2 = 1000.0 * accel_mps2
        self.decel_mmps2 = 1000.0 * decel_mps2
        self.decel_mps2 = float(decel_mps2)
        self.max_speed_mps = float(max_speed_mps)
        self.dt_s = float(dt_s)
        # scene times count from the model's creation (a RealClock's origin is arbitrary)
        self.fault_at_s = None if fault_at_s is None else clock.now_s() + float(fault_at_s)
        self.fault_code = int(fault_code)
        self.faulted = False
        # On a RealClock the controller's thread and the mocks' serving threads all advance the arm.
        self._lock = threading.RLock()
        self._t = clock.now_s()
        self._p = np.array(start, dtype=float)
        self._v = np.zeros(4)
        self._target: np.ndarray | None = None
        self._speed_mmps = 0.0
        self._pending: list[tuple[float, np.ndarray | None, float]] = []  # (t_effective, target, speed)
        self.history: Timeline[tuple[np.ndarray, np.ndarray]] = Timeline(keep_s=30.0)
        self.history.append(self._t, (self._p.copy(), self._v.copy()))
        self.commands = 0

    # -- Motion ---------------------------------------------------------------------------------
    @renamed_kwargs(speed_mps="path_speed_mps")
    def move_toward(self, target: Any, path_speed_mps: float) -> None:
        self.advance_to(self.clock.now_s())
        self._check_fault()
        if not (path_speed_mps > 0 and math.isfinite(path_speed_mps)):
            raise ValueError(f"arm: path_speed_mps={path_speed_mps!r} must be positive and finite")
        speed = min(float(path_speed_mps), self.max_speed_mps) * 1000.0
        tgt = np.array([target.x_mm, target.y_mm, target.z_mm, target.theta_deg], dtype=float)
        self._pending.append((self._t + self.command_latency_s, tgt, speed))
        self.commands += 1

    def pose(self) -> Pose:
        """The end effector's pose now (mm, deg)."""
        self.advance_to(self.clock.now_s())
        self._check_fault()
        return Pose(*map(float, self._p))

    def stop(self) -> None:
        """Brake to a halt after the command latency; safe at any time, also after a fault."""
        self.advance_to(self.clock.now_s())
        self._pending.append((self._t + self.command_latency_s, None, 0.0))

    # -- what tests and the scene runner look at ------------------------------------------------
    def position_at(self, t_s: float) -> np.ndarray:
        """(x, y, z mm, θ deg) at a past time (from the history)."""
        self.advance_to(max(t_s, self._t))
        t_i = self.history.time_at(t_s)
        p, v = self.history.at(t_s)
        return p + v * max(0.0, t_s - t_i)

    def speed_mps(self) -> float:
        self.advance_to(self.clock.now_s())
        return _norm(self._v) / 1000.0

    def is_moving(self) -> bool:
        """Moving, or a move is commanded (pending or active)."""
        self.advance_to(self.clock.now_s())
        return self.speed_mps() > 1e-6 or self._target is not None or any(
            tg is not None for _, tg, _ in self._pending)

    # -- physics ----------------------------------------------------------------------------------
    def _check_fault(self) -> None:
        if self.faulted:
            raise DeviceFault("protective stop latched (simulated arm fault)", device="arm",
                              code=self.fault_code, detail="protective stop")

    def advance_to(self, t_s: float) -> None:
        with self._lock:
            while self._t < t_s - 1e-12:
                jump = self._coast_s(t_s)
                if jump > self.dt_s:
                    # at rest or cruising: the state is linear in time, so take one exact step
                    self._p = self._p + self._v * jump
                    self._t += jump
                    self.history.append(self._t, (self._p.copy(), self._v.copy()))
                    continue
                dt = min(self.dt_s, t_s - self._t)
                self._integrate(dt)

    def _coast_s(self, t_s: float) -> float:
        """How long the motion stays exactly linear from now (0 when it is changing)."""
        horizon = t_s - self._t
        if self._pending:
            horizon = min(horizon, self._pending[0][0] - self._t)
        if self.fault_at_s is not None and not self.faulted:
            horizon = min(horizon, self.fault_at_s - self._t)
        speed = _norm(self._v)
        if self._target is None:
            return horizon if speed == 0.0 else 0.0
        d = self._target - self._p
        dist = _norm(d)
        if speed == 0.0 or dist < 1e-9 or abs(speed - self._speed_mmps) > 1e-9 * max(1.0, speed):
            return 0.0
        if _norm(self._v - d / dist * speed) > 1e-9 * max(1.0, speed):
            return 0.0
        brake_mm = speed * speed / (2.0 * self.decel_mmps2) + 2.0 * speed * self.dt_s
        return max(0.0, min(horizon, (dist - brake_mm) / speed))

    def _integrate(self, dt: float) -> None:
        t_new = self._t + dt
        while self._pending and self._pending[0][0] <= t_new:
            _, tgt, speed = self._pending.pop(0)
            self._target, self._speed_mmps = tgt, speed
        if self.fault_at_s is not None and not self.faulted and t_new >= self.fault_at_s:
            self.faulted = True
            self._target = None
            self._pending.clear()
        if self._target is None:
            v_des = np.zeros(4)
        else:
            d = self._target - self._p
            dist = _norm(d)
            if dist < 1e-6:
                v_des = np.zeros(4)
                self._p = self._target.copy()
                self._target = None if _norm(self._v) < 1e-6 else self._target
            else:
                # brake in time to stop on the target
                s = min(self._speed_mmps, math.sqrt(2.0 * self.decel_mmps2 * dist))
                v_des = d / dist * s
        dv = v_des - self._v
        if self.tracking_tau_s > 0:
            dv *= min(1.0, dt / self.tracking_tau_s)
        braking = _norm(v_des) < _norm(self._v)
        lim = (self.decel_mmps2 if braking else self.accel_mmps2) * dt
        n = _norm(dv)
        if n > lim:
            dv *= lim / n
        self._v = self._v + dv
        if _norm(v_des - self._v) < 1e-6:
            self._v = v_des.copy()
        if self._target is None and _norm(self._v) < 1e-3:
            self._v = np.zeros(4)
        self._p = self._p + self._v * dt
        if self._target is not None:
            # never pass the target (the planner stops on it)
            d_after = self._target - self._p
            if float(np.dot(d_after, self._target - (self._p - self._v * dt))) <= 0:
                self._p = self._target.copy()
                self._v = np.zeros(4)
                self._target = None
        self._t = t_new
        self.history.append(self._t, (self._p.copy(), self._v.copy()))


@register_model("arm")
def _arm(world: Any, rng: np.random.Generator, *, start: list[float] | None = None,
         start_mm: list[float] | None = None, **params: Any) -> SimArm:
    """Scene model: ``start_mm = [x, y, z, theta_deg]`` and the :class:`SimArm` parameters."""
    s = start_mm if start_mm is not None else start
    return SimArm(world.clock, start=tuple(s) if s is not None else (0.0, 0.0, 0.0, 0.0), **params)  # type: ignore[arg-type]
