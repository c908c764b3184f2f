"""The gripper plant: an MX-64 driving two fingers, an optional object between them, and heat.

Quasi-static model, integrated lazily up to a time (``advance_to``):

* The servo's profile generator moves a trajectory point toward the goal at the commanded speed
  (capped at the no-load speed, 63 rpm at 12 V). The shaft follows the trajectory while the
  current needed to hold it there stays below the current cap; otherwise it stops where the
  external force balances the capped current (a stall: present current saturates at the cap).
* External force: the object of ``object_width_m`` and ``object_stiffness_npm`` (a linear spring)
  once the opening is below its width; hard stops at the closed and fully open ends.
* Motor: force at the fingertips per ampere ``force_per_a_n`` (torque constant / finger lever);
  free motion draws a friction current; the stall current of the winding is V/R.
* Heat: one thermal mass, I²R heating against a thermal resistance to ambient, integrated exactly
  for piecewise-constant current. The firmware (not this model) decides when that latches an
  Overheating or Overload error.

Ticks are the MX-64's 4096 per revolution; opening grows with ticks between ``closed_ticks`` and
``open_ticks`` (``max_opening_m``).
"""

from __future__ import annotations

import math
from typing import Any

from tactile_rig.devices.dynamixel.control_table import NO_LOAD_RPM, STALL_CURRENT_A, TICKS_PER_REV
from tactile_rig.sim.base import register_model

COIL_RESISTANCE_OHM = 12.0 / STALL_CURRENT_A  # the winding: stall current at 12 V is V / R
# A rigid part (wood, hard plastic) between rubber finger pads: ~100 N/mm, so 100 N of grip squeezes
# it by 1 mm. (5 kN/m would let a 40 mm object be squashed to 20 mm at 40 % effort.)
OBJECT_STIFFNESS_NPM = 1.0e5


class Fingers:
    """Finger positions, motor current and winding temperature of a one-servo parallel gripper."""

    def __init__(
        self,
        world: Any = None,
        rng: Any = None,
        *,
        closed_ticks: int = 1024,
        open_ticks: int = 3072,
        max_opening_m: float = 0.10,
        position_ticks: float | None = None,
        object_width_m: float | None = None,
        object_stiffness_npm: float = OBJECT_STIFFNESS_NPM,
        force_per_a_n: float = 40.0,
        stop_stiffness_npm: float = 2.0e5,
        friction_current_a: float = 0.15,
        ambient_c: float = 30.0,
        thermal_resistance_k_per_w: float = 3.0,
        thermal_capacity_j_per_k: float = 8.0,
        t_s: float = 0.0,
    ) -> None:
        if open_ticks == closed_ticks:
            raise ValueError("fingers: open_ticks must differ from closed_ticks")
        if max_opening_m <= 0:
            raise ValueError(f"fingers: max_opening_m={max_opening_m!r} must be > 0")
        if object_width_m is not None and not 0 <= object_width_m <= max_opening_m:
            raise ValueError(f"fingers: object_width_m={object_width_m!r} must lie in [0, {max_opening_m}] m")
        self.closed_ticks = float(closed_ticks)
        self.open_ticks = float(open_ticks)
        self.max_opening_m = float(max_opening_m)
        self.object_width_m = None if object_width_m is None else float(object_width_m)
        self.object_stiffness_npm = float(object_stiffness_npm)
        self.force_per_a_n = float(force_per_a_n)
        self.stop_stiffness_npm = float(stop_stiffness_npm)
        self.friction_current_a = float(friction_current_a)
        self.ambient_c = float(ambient_c)
        self.r_th = float(thermal_resistance_k_per_w)
        self.c_th = float(thermal_capacity_j_per_k)
        start = (closed_ticks + open_ticks) / 2 if position_ticks is None else position_ticks
        self.position_ticks = float(start)
        self.trajectory_ticks = float(start)
        self.velocity_tps = 0.0  # ticks per second
        self.current_a = 0.0
        self.temperature_c = self.ambient_c
        # commands (set by the servo firmware)
        self.torque_on = False
        self.goal_ticks = float(start)
        self.speed_limit_tps = NO_LOAD_RPM / 60 * TICKS_PER_REV
        self.current_cap_a = STALL_CURRENT_A
        self.t_s = float(t_s)

    # -- geometry --------------------------------------------------------------------------
    @property
    def m_per_tick(self) -> float:
        return self.max_opening_m / (self.open_ticks - self.closed_ticks)

    def opening_m(self, ticks: float | None = None) -> float:
        """Distance between the fingertips at ``ticks`` (default: now), in metres."""
        p = self.position_ticks if ticks is None else ticks
        return (p - self.closed_ticks) * self.m_per_tick

    def external_force_n(self, ticks: float) -> float:
        """Force on the fingers along the opening direction (positive pushes them open)."""
        w = self.opening_m(ticks)
        f = 0.0
        if self.object_width_m is not None and w < self.object_width_m:
            f += self.object_stiffness_npm * (self.object_width_m - w)
        if w < 0:
            f += self.stop_stiffness_npm * -w
        if w > self.max_opening_m:
            f -= self.stop_stiffness_npm * (w - self.max_opening_m)
        return f

    def _holding_current_a(self, ticks: float) -> float:
        """Signed current (positive opens) that balances the external force at ``ticks``."""
        sign = 1.0 if self.open_ticks > self.closed_ticks else -1.0
        return -sign * self.external_force_n(ticks) / self.force_per_a_n

    # -- commands ----------------------------------------------------------------------------
    def command(self, *, torque_on: bool | None = None, goal_ticks: float | None = None,
                speed_limit_tps: float | None = None, current_cap_a: float | None = None) -> None:
        """Change the drive's commands (call :meth:`advance_to` up to now first)."""
        if torque_on is not None:
            if torque_on and not self.torque_on:
                self.trajectory_ticks = self.position_ticks  # the profile starts where the shaft is
            self.torque_on = bool(torque_on)
        if goal_ticks is not None and float(goal_ticks) != self.goal_ticks:
            # A new goal starts a new profile from where the shaft is (no wind-up after a stall).
            self.goal_ticks = float(goal_ticks)
            self.trajectory_ticks = self.position_ticks
        if speed_limit_tps is not None:
            no_load = NO_LOAD_RPM / 60 * TICKS_PER_REV
            self.speed_limit_tps = no_load if speed_limit_tps <= 0 else min(speed_limit_tps, no_load)
        if current_cap_a is not None:
            self.current_cap_a = min(abs(float(current_cap_a)), STALL_CURRENT_A)

    def reset_drive(self) -> None:
        """Torque off, trajectory at the shaft (a reboot)."""
        self.torque_on = False
        self.trajectory_ticks = self.goal_ticks = self.position_ticks

    # -- integration -------------------------------------------------------------------------
    def advance_to(self, t_s: float) -> None:
        dt = t_s - self.t_s
        if dt <= 0:
            return
        self.t_s = t_s
        p0 = self.position_ticks
        if self.torque_on:
            err = self.goal_ticks - self.trajectory_ticks
            step = self.speed_limit_tps * dt
            self.trajectory_ticks = self.goal_ticks if abs(err) <= step else self.trajectory_ticks + math.copysign(step, err)
            target = self.trajectory_ticks
            need = self._holding_current_a(target)
            if abs(need) <= self.current_cap_a:
                p, current = target, need
            else:
                # Saturated: the shaft stops where the external force balances the capped current.
                current = math.copysign(self.current_cap_a, need)
                # The holding current grows monotonically with the opening, so the balance lies
                # beyond the trajectory point when the load pushes that way, before it otherwise.
                span = 2.0 * abs(self.open_ticks - self.closed_ticks)
                ahead = (need < 0) == (self.open_ticks > self.closed_ticks)
                p = self._solve_ticks(target, target + (span if ahead else -span), current)
            if p != p0 and abs(current) < self.current_cap_a:
                current += math.copysign(min(self.friction_current_a, self.current_cap_a - abs(current)), p - p0)
        else:
            # The 200:1 gear train holds the fingers where they are when the torque is off.
            p, current = p0, 0.0
        self.velocity_tps = (p - p0) / dt
        self.position_ticks = p
        self.current_a = current
        self._heat(current, dt)

    def _solve_ticks(self, lo: float, hi: float, current_a: float) -> float:
        """Position in [lo, hi] where the holding current equals ``current_a`` (bisection)."""
        f_lo = self._holding_current_a(lo) - current_a
        f_hi = self._holding_current_a(hi) - current_a
        if f_lo * f_hi > 0:  # no crossing in between: stay on the side closest to balance
            return lo if abs(f_lo) <= abs(f_hi) else hi
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            f_mid = self._holding_current_a(mid) - current_a
            if f_mid * f_lo > 0:
                lo, f_lo = mid, f_mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def _heat(self, current_a: float, dt: float) -> None:
        t_ss = self.ambient_c + current_a * current_a * COIL_RESISTANCE_OHM * self.r_th
        self.temperature_c = t_ss + (self.temperature_c - t_ss) * math.exp(-dt / (self.r_th * self.c_th))

    @property
    def stall_current_a(self) -> float:
        return STALL_CURRENT_A


@register_model("fingers")
def _fingers_factory(world: Any, rng: Any, **params: Any) -> Fingers:
    return Fingers(world, rng, **params)
