"""The byte-free fakes' old public names still work for one release, each with a DeprecationWarning."""

from __future__ import annotations

import pytest

from tactile_rig.control.protocols import ForceGauge, Gripper, Motion
from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.geometry import Pose
from tactile_rig.core.types import GripperOutcome
from tactile_rig.sim.fakes.arm import SimArm
from tactile_rig.sim.fakes.gripper import SimGripper
from tactile_rig.sim.fakes.sensors import ModelGauge


def test_the_sim_gripper_takes_its_old_keywords_with_a_warning() -> None:
    g = SimGripper(VirtualClock())
    assert isinstance(g, Gripper)
    with pytest.warns(DeprecationWarning, match=r"gripper_go\(position=\.\.\.\) is deprecated: use opening_m="):
        assert g.gripper_go(position=0.05, effort_frac=0.3) == GripperOutcome.REACHED
    assert g.state().opening_m == pytest.approx(0.05, abs=1e-3)


def test_the_sim_arm_takes_speed_mps_with_a_warning_and_moves_as_path_speed_mps() -> None:
    clock = VirtualClock()
    old, new = SimArm(clock), SimArm(clock)
    assert isinstance(new, Motion)
    target = Pose(10.0, 0.0, 0.0, 0.0)
    with pytest.warns(DeprecationWarning, match=r"move_toward\(speed_mps=\.\.\.\) is deprecated"):
        old.move_toward(target, speed_mps=0.01)
    new.move_toward(target, path_speed_mps=0.01)
    clock.sleep(0.5)
    assert old.pose() == new.pose() and 4.0 < new.pose().x_mm < 6.0  # 10 mm/s for about half a second


def test_the_gauges_read_n_warns_and_reads_the_force() -> None:
    gauge = ModelGauge(VirtualClock(), lambda t: 2.5)
    assert isinstance(gauge, ForceGauge)
    assert gauge.read_force_n() == 2.5
    with pytest.warns(DeprecationWarning, match=r"ModelGauge\.read_n is deprecated: use \.read_force_n"):
        assert gauge.read_n() == 2.5
