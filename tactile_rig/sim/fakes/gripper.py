"""An ideal parallel gripper that implements the ``Gripper`` protocol directly (model kind "sim_gripper").

For scenes that test a controller rather than the servo: no bytes, no control table. The fingers
move toward the commanded opening at ``speed_mps`` after ``command_latency_s``; on an object of
width ``w`` (told by the grasped-object model) the skin is a spring of ``stiffness_n_per_m``, and
the squeeze is capped by ``effort × stall_force_n`` (the current limit): a command below ``w``
squeezes with ``min(k (w − goal), effort · stall)`` and the fingers stop where the skin balances it.
The Dynamixel mock with the ``fingers`` plant is the faithful version of the same thing.

``overload_at_s`` latches an Overload hardware error at that time: torque off, and every call
raises :class:`~tactile_rig.core.errors.DeviceFault` naming ``gripper``.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.core.deprecation import renamed_kwargs
from tactile_rig.core.errors import DeviceFault, check_range
from tactile_rig.core.types import GripperOutcome, GripperState
from tactile_rig.devices.dynamixel.control_table import STALL_CURRENT_A
from tactile_rig.sim.base import register_model
from tactile_rig.sim.world.timeline import Timeline

OVERLOAD_BIT = 0x20  # Hardware Error Status bit 5 of the MX series


class SimGripper:
    """A simulated gripper; ``width_fn(t_s)`` returns the width (m) of the object between the
    fingers, or None when there is none (set by the grasped-object model)."""

    name = "gripper"

    def __init__(self, clock: Clock, *, opening_m: float = 0.08, max_opening_m: float = 0.10,
                 speed_mps: float = 0.1, stall_force_n: float = 40.0, stiffness_n_per_m: float = 1.0e4,
                 command_latency_s: float = 0.004, dt_s: float = 0.001, effort: float = 0.3,
                 overload_at_s: float | None = None) -> None:
        check_range("gripper.opening_m", opening_m, 0.0, max_opening_m, "m")
        check_range("gripper.speed_mps", speed_mps, 1e-4, 5.0, "m/s")
        check_range("gripper.stall_force_n", stall_force_n, 1e-3, 1e4, "N")
        self.clock = clock
        self.max_opening_m = float(max_opening_m)
        self.speed_mps = float(speed_mps)
        self.stall_force_n = float(stall_force_n)
        self.stiffness_n_per_m = float(stiffness_n_per_m)
        self.command_latency_s = float(command_latency_s)
        self.dt_s = float(dt_s)
        self.overload_at_s = None if overload_at_s is None else clock.now_s() + float(overload_at_s)
        self.width_fn: Callable[[float], float | None] = lambda t: None
        self._t = clock.now_s()
        self._free_m = float(opening_m)  # where the fingers would be without an object
        self._goal_m = float(opening_m)
        self._effort = float(check_range("gripper.effort", effort, 0.0, 1.0))
        self._pending: list[tuple[float, float, float]] = []
        self.hardware_error = 0
        self.torque_on = True
        self.history: Timeline[tuple[float, float, float]] = Timeline()  # (opening, squeeze, velocity)
        self._opening = float(opening_m)
        self._squeeze = 0.0
        self._vel = 0.0
        self.history.append(self._t, (self._opening, 0.0, 0.0))
        self.commands: list[tuple[float, float, float]] = []  # (t, goal, effort) as issued

    # -- Gripper protocol ----------------------------------------------------------------------
    @renamed_kwargs(position="opening_m", effort="effort_frac")
    def gripper_go(self, opening_m: float, effort_frac: float, *, blocking: bool = True,
                   timeout_s: float | None = None) -> Any:

        self.advance_to(self.clock.now_s())
        self._check_fault()
        check_range("gripper_go opening_m", float(opening_m), 0.0, self.max_opening_m, "m")
        check_range("gripper_go effort_frac", float(effort_frac), 0.0, 1.0)
        self._pending.append((self._t + self.command_latency_s, float(opening_m), float(effort_frac)))
        self.commands.append((self._t, float(opening_m), float(effort_frac)))
        if not blocking:
            return GripperOutcome.MOVING
        t_end = math.inf if timeout_s is None else self._t + timeout_s
        self.clock.sleep(self.command_latency_s + self.dt_s)
        while True:
            self.advance_to(self.clock.now_s())
            self._check_fault()
            closing_on_object = self._goal_m < self._opening and self._squeeze >= self._effort * self.stall_force_n
            if (abs(self._free_m - self._goal_m) < 1e-9 or closing_on_object) and abs(self._vel) < 1e-6:
                if abs(self._opening - self._goal_m) < 2e-4:
                    return GripperOutcome.REACHED
                return GripperOutcome.STALLED
            if self._t >= t_end:
                return GripperOutcome.TIMEOUT
            self.clock.sleep(0.005)

    def state(self) -> Any:
        self.advance_to(self.clock.now_s())
        self._check_fault()
        squeeze = self._squeeze
        return GripperState(t_s=self._t, opening_m=self._opening,
                            opening_frac=self._opening / self.max_opening_m, velocity_mps=self._vel,
                            current_a=-squeeze / self.stall_force_n * STALL_CURRENT_A,
                            effort_frac=min(1.0, squeeze / self.stall_force_n), temperature_c=35.0,
                            hardware_error=self.hardware_error, moving=abs(self._vel) > 1e-6,
                            active=self.torque_on)

    # -- for the world ----------------------------------------------------------------------------
    def set_width_fn(self, width_fn: Callable[[float], float | None]) -> None:
        """Attach the object model and settle the squeeze on it at the current time."""
        self.width_fn = width_fn
        w = width_fn(self._t)
        if w is not None and self._free_m < w:
            cap = self._effort * self.stall_force_n
            self._squeeze = min(self.stiffness_n_per_m * (w - self._free_m), cap)
            self._opening = w - self._squeeze / self.stiffness_n_per_m
            self.history.append(self._t, (self._opening, self._squeeze, 0.0))

    def squeeze_at(self, t_s: float) -> float:
        """Normal force (N) on the object at a past time."""
        self.advance_to(max(t_s, self._t))
        return self.history.at(t_s)[1]

    def opening_at(self, t_s: float) -> float:
        self.advance_to(max(t_s, self._t))
        return self.history.at(t_s)[0]

    def _check_fault(self) -> None:
        if self.hardware_error:
            raise DeviceFault("Overload error latched: torque is off", device="gripper",
                              code=self.hardware_error, detail="overload")

    def advance_to(self, t_s: float) -> None:
        while self._t < t_s - 1e-12:
            if not self._pending and self._vel == 0.0 and abs(self._free_m - self._goal_m) < 1e-12 and (
                    self.overload_at_s is None or self.hardware_error):
                # at rest with nothing scheduled; the object may still appear or vanish: step coarsely
                dt = min(t_s - self._t, 0.01)
            else:
                dt = min(self.dt_s, t_s - self._t)
            self._integrate(dt)

    def _integrate(self, dt: float) -> None:
        t_new = self._t + dt
        while self._pending and self._pending[0][0] <= t_new:
            _, self._goal_m, self._effort = self._pending.pop(0)
        if self.overload_at_s is not None and not self.hardware_error and t_new >= self.overload_at_s:
            self.hardware_error = OVERLOAD_BIT
            self.torque_on = False
            self._goal_m = self._free_m  # torque off: the gears hold the fingers where they are
        prev = self._opening
        if self.torque_on:
            step = self.speed_mps * dt
            err = self._goal_m - self._free_m
            self._free_m = self._goal_m if abs(err) <= step else self._free_m + math.copysign(step, err)
        w = self.width_fn(t_new)
        squeeze = 0.0
        opening = self._free_m
        if w is not None and self._free_m < w:
            cap = self._effort * self.stall_force_n if self.torque_on else math.inf
            squeeze = min(self.stiffness_n_per_m * (w - self._free_m), cap)
            # the trajectory point runs on to the goal; the fingers stop where the skin balances
            opening = w - squeeze / self.stiffness_n_per_m
        self._opening = opening
        self._squeeze = squeeze
        self._vel = (opening - prev) / dt if dt > 0 else 0.0
        self._t = t_new
        self.history.append(t_new, (opening, squeeze, self._vel))


@register_model("sim_gripper")
def _sim_gripper(world: Any, rng: np.random.Generator, **params: Any) -> SimGripper:
    """Scene model: the :class:`SimGripper` parameters (SI units)."""
    return SimGripper(world.clock, **params)
