"""The lifecycle every driver shares (drivers/base.py): connected → active → fault → active, closed."""

from __future__ import annotations

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import DeviceFault, GrblAlarm, NotConnected
from tactile_rig.drivers.base import Driver, Lifecycle
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.sim import World
from tactile_rig.testing import serve_in_process


class _Probe(Driver):
    def __init__(self) -> None:
        super().__init__("probe")
        self.calls: list[str] = []

    def _activate(self) -> None:
        self.calls.append("activate")

    def _deactivate(self) -> None:
        self.calls.append("deactivate")

    def _close(self) -> None:
        self.calls.append("close")


def test_base_transitions_and_guards() -> None:
    d = _Probe()
    assert d.lifecycle is Lifecycle.CONNECTED
    d.activate()
    assert d.lifecycle is Lifecycle.ACTIVE
    err = d.fault(DeviceFault("overload", device="probe", code=32))
    assert d.lifecycle is Lifecycle.FAULT and d.last_fault is err
    with pytest.raises(DeviceFault, match="move refused: the device is in fault: probe: overload") as info:
        d.require_not_faulted("move")
    assert info.value.code == 32
    d.deactivate()  # allowed in fault, stays in fault
    assert d.lifecycle is Lifecycle.FAULT
    d.activate()
    assert d.lifecycle is Lifecycle.ACTIVE and d.last_fault is None
    with d:
        pass
    assert d.closed and d.calls == ["activate", "deactivate", "activate", "close"]
    d.close()  # idempotent: _close runs once
    assert d.calls.count("close") == 1
    with pytest.raises(NotConnected, match="_Probe was closed"):
        d.activate()


def _jig(**kw):
    clock = VirtualClock()
    world = World(clock)
    stage = world.build("stage", "stage")
    return clock, GrblMock(clock=clock, stage=stage, **kw)


def test_jig_is_connected_while_locked_active_once_homed_and_faults_on_an_alarm() -> None:
    clock, mock = _jig()
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        assert jig.lifecycle is Lifecycle.CONNECTED  # GRBL booted in its homing lock
        jig.activate()  # homes
        assert jig.lifecycle is Lifecycle.ACTIVE and jig.status().state == "Idle"
        jig.move_to(10.0, 0.0, 0.0)
        clock.advance(0.5)
        mock.inject("hard_limit", axis="Y")
        with pytest.raises(GrblAlarm, match="ALARM:1"):
            jig.wait_idle(5.0)
        assert jig.lifecycle is Lifecycle.FAULT
        with pytest.raises(DeviceFault, match="move_to refused.*ALARM:1"):
            jig.move_to(0.0, 0.0, 0.0)
        jig.activate()  # soft reset (a hard limit needs one), then home again
        assert jig.lifecycle is Lifecycle.ACTIVE
        jig.move_to(1.0, 0.0, 0.0, wait=True)
        assert jig.pose().x_mm == pytest.approx(1.0, abs=1e-3)
        jig.close()
        assert jig.closed


def test_jig_without_homing_is_active_at_once() -> None:
    clock, mock = _jig(homing=False)
    with serve_in_process(mock, clock) as url, Jig(url) as jig:
        assert jig.lifecycle is Lifecycle.ACTIVE
    assert jig.closed


def test_scale_is_a_driver_that_closes_once() -> None:
    with Scale("rigsim://scale?rate=80") as scale:
        assert scale.lifecycle is Lifecycle.CONNECTED
        scale.read(timeout_s=1.0)
    assert scale.closed
    scale.close()
    with pytest.raises(NotConnected):
        scale.read(timeout_s=0.1)
