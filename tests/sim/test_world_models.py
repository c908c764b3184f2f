"""The world models the controller scenes are built on: the arm's latency and braking, the
gripper's effort cap, the friction model's slip threshold, the sensor's frame timing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.control.protocols import Pose, TouchReading
from tactile_rig.core.errors import DeviceTimeout
from tactile_rig.sim.fakes.sensors import ModelSensor
from tactile_rig.sim import World
from tactile_rig.sim.fakes.arm import SimArm


@settings(max_examples=20)
@given(dx=st.floats(-50, 50), dz=st.floats(-50, 50), speed=st.floats(0.001, 0.2), latency=st.floats(0.0, 0.05))
def test_the_arm_waits_its_latency_never_passes_its_target_and_brakes_within_v2_over_2a(dx, dz, speed, latency) -> None:
    clock = VirtualClock()
    arm = SimArm(clock, command_latency_s=latency, decel_mps2=5.0)
    arm.move_toward(Pose(dx, 0.0, dz, 0.0), speed)
    clock.sleep(latency * 0.99)
    assert arm.pose() == Pose(0.0, 0.0, 0.0, 0.0)
    dist = math.hypot(dx, dz)
    clock.sleep(dist / (1000 * speed) / 2 + 0.05)
    p = arm.pose()
    assert math.hypot(p.x_mm, p.z_mm) <= dist + 1e-9  # along the way, not past it
    v = arm.speed_mps()
    arm.stop()
    at_stop = np.array(arm.position_at(clock.now_s())[:3])
    clock.sleep(latency + 1.0)
    assert not arm.is_moving()
    moved_mm = float(np.linalg.norm(arm.position_at(clock.now_s())[:3] - at_stop))
    assert moved_mm <= 1000 * (v * (latency + 0.02) + v * v / (2 * 5.0)) + 1e-6


@settings(max_examples=15)
@given(mass=st.floats(0.05, 1.0), mu=st.floats(0.3, 1.0), margin=st.floats(0.3, 0.95))
def test_an_object_holds_above_the_friction_threshold_and_slips_below_it(mass, mu, margin) -> None:
    def hang(effort_scale: float) -> float:
        world = World(VirtualClock())
        g = world.build("gripper", "sim_gripper", opening_m=0.0, stall_force_n=40.0, effort=0.5)
        obj = world.build("object", "grasped_object", mass_kg=mass, mu_static=mu, width_m=0.03,
                          contact_length_mm=1000.0, gripper="gripper")
        need = obj.min_squeeze_n() / g.stall_force_n * effort_scale
        g.gripper_go(0.0, min(1.0, need), blocking=False)
        world.clock.sleep(0.5)
        return obj.state_at(world.clock.now_s()).slip_mm

    assert hang(1.02) < 0.01  # just above the threshold: stuck
    assert hang(margin) > 1.0  # below it: it slides


def test_the_model_sensor_paces_frames_and_a_frozen_camera_times_out() -> None:
    clock = VirtualClock()
    s = ModelSensor(clock, lambda t: TouchReading(t, force_n=(0, 0, t)), rate_hz=20.0, latency_s=0.01,
                    freeze_at_s=0.3, name="cam")
    stamps = [s.read(1.0).t_s for _ in range(6)]
    assert stamps == pytest.approx([0.0, 0.05, 0.1, 0.15, 0.2, 0.25])
    assert clock.now_s() == pytest.approx(0.26)  # each frame delivered one latency after capture
    with pytest.raises(DeviceTimeout, match="no new frame"):
        s.read(0.2)
