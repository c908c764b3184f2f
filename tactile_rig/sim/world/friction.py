"""A grasped object with Coulomb friction: slips, rotates in the hand, or drops (kind "grasped_object").

The object hangs between two fingers that squeeze it with ``N`` (from the gripper model); a hand
(optional) may carry part of its weight and press it on one fingertip; the arm (optional) may lift
the fingers, adding its vertical acceleration to gravity; a table (``on_table``) may hold it up.

Translation along gravity (``slip_mm``, down positive, relative to the fingers): stuck while the
net load ``m (g + a_arm) − hand support`` stays within ``μs (2N + press)``; slipping, it
accelerates under the load minus kinetic friction ``μk (2N + press)``. Past ``contact_length_mm``
of slip it leaves the fingertips: dropped.

Rotation about the grasp axis (``angle_deg``, 0 = horizontal, 90 = hanging), when the centre of
mass sits ``com_offset_mm`` from the grasp: gravity torque ``m g r cos θ`` against the friction
torque of the contact patches ``μ 2N r_patch``, with inertia ``m r²`` and viscous damping of the
skin. The true minimum grip to lift the object without slip is
``m (g + a_max) / (2 μs)`` of squeeze (:meth:`GraspedObject.min_squeeze_n`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model
from tactile_rig.sim.world.timeline import Timeline

# The simulated world's gravity, a model choice (not devices.scale.STANDARD_GRAVITY_MPS2, the scale's grams to newtons).
G_MPS2 = 9.81


@dataclass(slots=True)
class _State:
    """The grasped object's state at one instant (mm, mm/s, deg, deg/s, N, N·mm)."""

    slip_mm: float = 0.0
    v_mmps: float = 0.0
    angle_deg: float = 0.0
    omega_dps: float = 0.0
    squeeze_n: float = 0.0
    press_n: float = 0.0
    present: float = 0.0
    friction_n: float = 0.0
    torque_nmm: float = 0.0
    lift_mm: float = 0.0

    def copy(self) -> "_State":
        return replace(self)


class GraspedObject:
    """The object between the fingers; see the module docstring for the physics."""

    def __init__(self, world: Any, *, mass_kg: float = 0.1, mu_static: float = 0.6, mu_kinetic: float | None = None,
                 mu_kinetic_ratio: float = 0.85,
                 width_m: float = 0.03, contact_length_mm: float = 15.0, com_offset_mm: float = 0.0,
                 patch_radius_mm: float = 4.0, rot_damping_nmm_s_per_rad: float = 5.0,
                 start_angle_deg: float = 0.0, on_table: bool = False, gripper: str = "gripper",
                 hand: str | None = None, arm: str | None = None, dt_s: float = 0.001) -> None:
        check_range("grasped_object.mass_kg", mass_kg, 1e-4, 100.0, "kg")
        check_range("grasped_object.mu_static", mu_static, 1e-3, 5.0)
        if mu_kinetic is None:
            mu_kinetic = check_range("grasped_object.mu_kinetic_ratio", mu_kinetic_ratio, 0.05, 1.0) * mu_static
        check_range("grasped_object.mu_kinetic", mu_kinetic, 1e-3, mu_static)
        self.world = world
        self.mass_kg = float(mass_kg)
        self.mu_s = float(mu_static)
        self.mu_k = float(mu_kinetic)
        self.width_m = float(width_m)
        self.contact_length_mm = float(contact_length_mm)
        self.r_mm = float(com_offset_mm)
        self.patch_mm = float(patch_radius_mm)
        self.damping = float(rot_damping_nmm_s_per_rad)
        self.on_table = bool(on_table)
        self.dt_s = float(dt_s)
        self.gripper = world.require(gripper, who="grasped_object")
        self.hand = world.require(hand, who="grasped_object") if hand else None
        self.arm = world.require(arm, who="grasped_object") if arm else None
        self.dropped = False
        self.drop_t_s: float | None = None
        self._t = world.clock.now_s()
        self._s = _State(angle_deg=float(start_angle_deg))
        self._arm_z0 = self._arm_z(self._t)
        self._arm_v_prev = 0.0
        self.history: Timeline[_State] = Timeline()
        self.max_lift_accel_mps2 = 0.0
        self._attach_to_gripper()
        if self.present(self._t):
            self._s.squeeze_n = self._squeeze_n(self._t)
            self._s.present = 1.0
            if self.r_mm > 0:  # the torque the skin carries from the start
                self._rotate(0.0, self._s.squeeze_n, self.hand.holding_frac(self._t) if self.hand else 0.0)
        self.history.append(self._t, self._s.copy())

    # -- coupling --------------------------------------------------------------------------------
    def _attach_to_gripper(self) -> None:
        g = self.gripper
        if hasattr(g, "set_width_fn"):
            g.set_width_fn(lambda t: self.width_m if self.present(t) else None)
        elif hasattr(g, "object_width_m"):  # the Dynamixel ``fingers`` plant: a width it reads itself
            g.object_width_m = self.width_m if self.present(self._t) else None

    def _squeeze_n(self, t_s: float) -> float:
        g = self.gripper
        if hasattr(g, "squeeze_at"):
            return float(g.squeeze_at(t_s))
        g.advance_to(t_s)
        w = g.object_width_m
        if w is None:
            return 0.0
        return max(0.0, g.object_stiffness_npm * (w - g.opening_m()))

    def _arm_z(self, t_s: float) -> float:
        if self.arm is None:
            return 0.0
        return float(self.arm.position_at(t_s)[2])

    def present(self, t_s: float) -> bool:
        """Between the fingers: brought by the hand (if any), not carried away, not dropped."""
        if self.hand is not None and (t_s < self.hand.arrive_s or (
                t_s >= self.hand.leave_s and self.hand.holding_frac(self.hand.leave_s - 1e-9) > 0)):
            return False  # not brought yet, or carried away by the hand that still held it
        return not self.dropped

    # -- truth for the scene ----------------------------------------------------------------------
    def min_squeeze_n(self, accel_mps2: float = 0.0) -> float:
        """Least squeeze (N per finger pair) that holds the object at vertical acceleration ``accel``."""
        return self.mass_kg * (G_MPS2 + accel_mps2) / (2.0 * self.mu_s)

    def state_at(self, t_s: float) -> _State:
        self.advance_to(max(t_s, self._t))
        return self.history.at(t_s)

    def lifted_mm(self, t_s: float | None = None) -> float:
        """Height of the object above where it started (arm lift minus slip)."""
        t = self._t if t_s is None else t_s
        s = self.state_at(t)
        return s.lift_mm - s.slip_mm

    # -- physics -------------------------------------------------------------------------------
    def advance_to(self, t_s: float) -> None:
        while self._t < t_s - 1e-12:
            self._integrate(min(self.dt_s, t_s - self._t))

    def _integrate(self, dt: float) -> None:
        t = self._t + dt
        s = self._s
        present = self.present(t)
        if hasattr(self.gripper, "object_width_m") and not hasattr(self.gripper, "set_width_fn"):
            self.gripper.object_width_m = self.width_m if present else None
        n = self._squeeze_n(t) if present else 0.0
        hand_frac = self.hand.holding_frac(t) if self.hand is not None else 0.0
        press = self.hand.press_n(t) if self.hand is not None else 0.0
        z = self._arm_z(t)
        lift = z - self._arm_z0
        arm_v = (lift - s.lift_mm) / dt  # mm/s
        accel = (arm_v - self._arm_v_prev) / dt / 1000.0  # m/s²
        self._arm_v_prev = arm_v
        if present and n > 0:
            self.max_lift_accel_mps2 = max(self.max_lift_accel_mps2, accel)
        m = self.mass_kg
        grip = 2.0 * n + press
        friction = 0.0
        if self.dropped or not present:
            if self.dropped:  # free fall out of the fingers
                s.v_mmps += G_MPS2 * 1000.0 * dt
                s.slip_mm += s.v_mmps * dt
        elif self.hand is not None and hand_frac > 0 and self.hand.descend_mps > 0:
            s.v_mmps = 1000.0 * self.hand.descend_mps  # the hand drives it through the fingers
            s.slip_mm += s.v_mmps * dt
            friction = self.mu_k * grip if grip > 0 else 0.0
        else:
            load = m * (G_MPS2 + accel) * (1.0 - hand_frac)
            if s.v_mmps == 0.0 and abs(load) <= self.mu_s * grip:
                friction = load
            else:
                f_k = self.mu_k * grip * (1.0 if s.v_mmps > 0 or (s.v_mmps == 0 and load > 0) else -1.0)
                a = (load - f_k) / m * 1000.0  # mm/s²
                v_new = s.v_mmps + a * dt
                if s.v_mmps != 0.0 and v_new * s.v_mmps < 0:  # friction stops it: stick
                    v_new = 0.0
                s.v_mmps = v_new
                s.slip_mm += v_new * dt
                friction = f_k
            if self.on_table and s.slip_mm > lift:  # the table holds it up (and catches it: no drop)
                s.slip_mm = lift
                s.v_mmps = 0.0
        if present and not self.dropped and self.r_mm > 0:
            # a contact that slides has no friction left to resist a turn (limit surface coupling)
            self._rotate(dt, 0.0 if s.v_mmps != 0.0 else n, hand_frac)
        s.squeeze_n, s.press_n, s.present, s.friction_n, s.lift_mm = n, press, float(present), friction, lift
        if not self.dropped and present and hand_frac == 0.0 and not self.on_table and s.slip_mm > self.contact_length_mm:
            self.dropped = True
            self.drop_t_s = t
        self._t = t
        self.history.append(t, s.copy())

    def _rotate(self, dt: float, n: float, hand_frac: float) -> None:
        s = self._s
        m, r = self.mass_kg, self.r_mm
        tau_g = m * G_MPS2 * r * math.cos(math.radians(s.angle_deg)) * (1.0 - hand_frac)  # N·mm
        cap_s = self.mu_s * 2.0 * n * self.patch_mm
        cap_k = self.mu_k * 2.0 * n * self.patch_mm
        omega = math.radians(s.omega_dps)
        if omega == 0.0 and abs(tau_g) <= cap_s:
            s.torque_nmm = tau_g
            return
        sign = math.copysign(1.0, omega if omega != 0.0 else tau_g)
        tau = tau_g - cap_k * sign - self.damping * omega
        inertia = m * r * r  # kg·mm²
        w_new = omega + 1000.0 * tau / inertia * dt
        if omega != 0.0 and w_new * omega < 0:
            w_new = 0.0
        s.omega_dps = math.degrees(w_new)
        s.angle_deg += math.degrees(w_new) * dt
        s.torque_nmm = cap_k * sign


@register_model("grasped_object")
def _grasped_object(world: Any, rng: np.random.Generator, **params: Any) -> GraspedObject:
    """Scene model: the :class:`GraspedObject` parameters; ``gripper``/``hand``/``arm`` name models above it."""
    return GraspedObject(world, **params)
