"""Every controller stops its axes and returns a typed FAULT naming the device when a device
raises mid-run; a speed above the cap is refused before anything moves."""

from __future__ import annotations

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.control.collision_stop import CollisionStop, CollisionStopParams
from tactile_rig.control.common import Outcome
from tactile_rig.control.following import Following, FollowingParams
from tactile_rig.control.protocols import Gripper, Motion, Pose, TactileSensor, TouchReading
from tactile_rig.control.rotation import TorqueRotation, TorqueRotationParams
from tactile_rig.core.errors import DeviceTimeout, LimitError, NotConnected
from tactile_rig.sim.fakes.sensors import ModelSensor
from tactile_rig.sim.fakes.arm import SimArm
from tactile_rig.sim.fakes.gripper import SimGripper


def _rig(**arm_kw):
    clock = VirtualClock()
    arm = SimArm(clock, **arm_kw)
    sensor = ModelSensor(clock, lambda t: TouchReading(t, force_n=(0.0, 0.0, 0.0)), rate_hz=30.0)
    return clock, arm, sensor


def test_the_simulated_devices_satisfy_the_protocols() -> None:
    clock, arm, sensor = _rig()
    assert isinstance(arm, Motion) and isinstance(sensor, TactileSensor)
    assert isinstance(SimGripper(clock), Gripper)


def test_a_speed_above_the_cap_is_refused_before_anything_moves() -> None:
    clock, arm, sensor = _rig()
    cs = CollisionStop(arm, sensor, clock, CollisionStopParams(sensing_rate_hz=16.0, latency_s=0.0))
    cs.calibrate()
    with pytest.raises(LimitError, match="cap"):
        cs.run(Pose(0, 0, -50, 0), 0.017)
    assert arm.commands == 0 and not arm.is_moving()


def test_an_arm_fault_mid_approach_is_a_fault_outcome_and_the_arm_is_still() -> None:
    clock, arm, sensor = _rig(fault_at_s=0.5)
    res = CollisionStop(arm, sensor, clock).run(Pose(0, 0, -50, 0), 0.005)
    assert res.outcome is Outcome.FAULT and res.fault_device == "arm" and "protective stop" in res.message
    clock.sleep(1.0)
    assert not arm.is_moving()


def test_a_frozen_camera_mid_approach_stops_the_arm_within_a_frame() -> None:
    clock = VirtualClock()
    arm = SimArm(clock)
    sensor = ModelSensor(clock, lambda t: TouchReading(t), rate_hz=30.0, freeze_at_s=0.8, name="camera0")
    res = CollisionStop(arm, sensor, clock).run(Pose(0, 0, -50, 0), 0.005)
    assert res.outcome is Outcome.FAULT and res.fault_device == "camera0"
    # the watchdog is one period plus the latency: it stopped right after the last frame
    assert clock.now_s() < 0.8 + 2.0 / 30.0 + 0.1
    clock.sleep(0.5)
    assert not arm.is_moving()


class _Unplugged:
    """A Motion whose link dies after some calls (EIO from a USB adapter), stop() included."""

    name = "jig@/dev/ttyUSB0"

    def __init__(self, arm: SimArm, calls: int) -> None:
        self.arm, self.calls = arm, calls
        self.stopped = 0

    def _tick(self) -> None:
        self.calls -= 1
        if self.calls < 0:
            raise NotConnected("port failed: unplugged (EIO)", device=self.name)

    def move_toward(self, target: Pose, path_speed_mps: float) -> None:
        self._tick()
        self.arm.move_toward(target, path_speed_mps)

    def pose(self) -> Pose:
        self._tick()
        return self.arm.pose()

    def stop(self) -> None:
        self.stopped += 1
        self.arm.stop()  # the axis's own safety stops it; the host's stop may not get through


@pytest.mark.parametrize("calls", [3, 10, 40])
def test_following_that_loses_its_axis_reports_the_device_and_calls_stop(calls) -> None:
    clock, arm, _ = _rig()
    sensor = ModelSensor(clock, lambda t: TouchReading(t, force_n=(2.0, 0.0, 1.0)), rate_hz=30.0)
    motion = _Unplugged(arm, calls)
    res = Following(motion, sensor, clock, FollowingParams(duration_s=3.0)).run()
    assert res.outcome is Outcome.FAULT and res.fault_device == "jig@/dev/ttyUSB0"
    assert motion.stopped >= 1
    clock.sleep(0.5)
    assert not arm.is_moving()


def test_torque_rotation_refuses_a_fast_turn_and_faults_on_a_silent_sensor() -> None:
    clock, arm, _ = _rig()
    silent = ModelSensor(clock, lambda t: TouchReading(t), rate_hz=30.0, freeze_at_s=0.2, name="fv")
    rot = TorqueRotation(arm, silent, clock, TorqueRotationParams(sensing_rate_hz=30.0))
    with pytest.raises(LimitError):
        rot.run(90.0, rot.cap_dps() * 1.5)
    res = rot.run(90.0, rot.cap_dps() * 0.5)
    assert res.outcome is Outcome.FAULT and res.fault_device == "fv"
    clock.sleep(0.5)
    assert not arm.is_moving()


def test_a_sensor_that_returns_nothing_is_a_timeout_fault() -> None:
    clock, arm, _ = _rig()

    class Empty:
        name = "empty"

        def read(self, timeout_s=None):
            clock.sleep(timeout_s or 0.1)
            return None

    res = Following(arm, Empty(), clock).run()
    assert res.outcome is Outcome.FAULT and res.fault_device == "empty"
    assert isinstance(DeviceTimeout("x"), TimeoutError)
