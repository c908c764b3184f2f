"""DynamixelBus and DynamixelGripper against the MX-64 mock: typed errors, lifecycle, plant."""

from __future__ import annotations

import logging
from contextlib import ExitStack

import pytest

from tactile_rig.control.protocols import Gripper, GripperOutcome
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.drivers.dynamixel.bus import CommandRejected, DynamixelBus, check_latency_timer
from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper, GripperCalibration, Lifecycle
from tactile_rig.core.errors import DeviceFault, DeviceTimeout, LimitError, LinkCorrupt, NotConnected, RigError
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.sim.world.fingers import Fingers
from tactile_rig.testing import serve_in_process


@pytest.fixture
def bus2():
    dev = make_bus(ids=[1, 2], timing=True, return_delay_us=0)
    with serve_in_process(dev) as url:
        with DynamixelBus(url) as bus:
            yield bus, dev


def test_bus_errors_are_typed_and_the_bus_keeps_working(bus2) -> None:
    bus, dev = bus2
    with pytest.raises(DeviceTimeout, match=r"dynamixel\[9\]"):
        bus.ping(9)
    bus.write(1, "Torque Enable", 1)
    with pytest.raises(CommandRejected) as info:
        bus.write(1, "Return Delay Time", 10)  # EEPROM with torque on
    assert info.value.error_number == de.ACCESS_ERROR and "Access Error" in str(info.value)
    with pytest.raises(LimitError, match="Goal Current=5000"):
        bus.write(1, "Goal Current", 5000)  # outside the item's range: refused before sending
    bus.write(1, "Torque Enable", 0)
    bus.write(1, "Current Limit", 500)
    with pytest.raises(CommandRejected) as info:
        bus.write(1, "Goal Current", 900)  # within range but above Current Limit
    assert info.value.error_number == de.DATA_LIMIT
    with pytest.raises(CommandRejected) as info:
        bus.write_bytes(1, 120, b"\x00\x00")  # Realtime Tick is read-only
    assert info.value.error_number == de.ACCESS_ERROR
    with pytest.raises(CommandRejected) as info:
        bus.write_bytes(1, 116, b"\x00\x00")  # half of Goal Position
    assert info.value.error_number == de.DATA_LENGTH
    assert bus.ping(1) == 311 and bus.ping(2) == 311


def test_sync_and_bulk_read_through_the_bus(bus2) -> None:
    bus, dev = bus2
    bus.sync_write("Goal Position", {1: 1200, 2: 2800})
    assert bus.sync_read([1, 2], "Goal Position") == {1: 1200, 2: 2800}
    assert bus.sync_read([1, 2], "Goal Position", fast=True) == {1: 1200, 2: 2800}
    assert bus.bulk_read([(1, "Model Number"), (2, "Goal Position")]) == {1: 311, 2: 2800}


def test_wrong_baud_gets_nothing_usable_then_the_right_baud_works() -> None:
    dev = make_bus(ids=[1], timing=True)
    with serve_in_process(dev) as url:
        with DynamixelBus(url, baudrate=57600) as wrong:
            with pytest.raises((DeviceTimeout, LinkCorrupt)):
                wrong.ping(1)
        with DynamixelBus(url, baudrate=1_000_000) as right:
            assert right.ping(1) == 311


def test_corrupt_reply_is_link_corrupt_and_the_next_read_works() -> None:
    with serve_in_process(make_bus(ids=[1], timing=True)) as url:
        with DynamixelBus(f"rigfault://{url}#flip=1.0&seed=1") as bus:
            with pytest.raises((LinkCorrupt, DeviceTimeout)):
                bus.read(1, "Present Position")
            bus.port.ser.faults.flip = 0.0
            assert bus.read(1, "Model Number") == 311


def test_cut_off_instruction_then_the_bus_recovers(bus2) -> None:
    bus, dev = bus2
    goal_before = dev.servo(1).item("Goal Position")
    # half of a write packet, as from a host that died mid-write
    bus.port.ser.write(bytes.fromhex("FF FF FD 00 01 09 00 03 74 00"))
    assert bus.read(1, "Model Number") == 311
    assert dev.servo(1).item("Goal Position") == goal_before  # the cut-off write had no effect


def test_corrupt_instruction_gets_crc_error(bus2) -> None:
    bus, dev = bus2
    from tactile_rig.mocks.dynamixel.codec import StreamParser, encode_p2

    pkt = bytearray(encode_p2(1, 0x02, bytes.fromhex("84 00 04 00")))
    pkt[-1] ^= 0xFF
    bus.port.ser.reset_input_buffer()
    bus.port.ser.write(bytes(pkt))
    bus.port.ser.timeout = 0.01
    reply = StreamParser(2, status=True).feed(bus.port.ser.read(11))
    assert reply[0].error == de.CRC_ERROR
    assert bus.ping(1) == 311


def test_latency_timer_warning(tmp_path, caplog) -> None:
    dev = tmp_path / "bus" / "usb-serial" / "devices" / "ttyUSB7"
    dev.mkdir(parents=True)
    (dev / "latency_timer").write_text("16\n")
    with caplog.at_level(logging.WARNING, logger="tactile_rig.dynamixel"):
        assert check_latency_timer("/dev/ttyUSB7", sysfs_root=tmp_path) == 16
    assert "latency timer is 16 ms" in caplog.text
    (dev / "latency_timer").write_text("1\n")
    caplog.clear()
    assert check_latency_timer("/dev/ttyUSB7", sysfs_root=tmp_path) == 1
    assert not caplog.text
    assert check_latency_timer("rigsim://dynamixel") is None


def test_unknown_port_is_not_connected() -> None:
    with pytest.raises(NotConnected, match="/dev/does-not-exist"):
        DynamixelBus("/dev/does-not-exist")


# -- the gripper ----------------------------------------------------------------------------------
@pytest.fixture
def gripper_factory():
    """``make(protocol, width_mm)`` → (gripper, bus device) with an object of ``width_mm`` (None: none)."""
    with ExitStack() as stack:

        def make(protocol: int = 2, width_mm: float | None = 40.0, **kw):
            plant = Fingers(object_width_m=None if width_mm is None else width_mm / 1000)
            dev = make_bus(protocol=protocol, ids=[1], timing=True, return_delay_us=0, plants={1: plant})
            url = stack.enter_context(serve_in_process(dev))
            return stack.enter_context(DynamixelGripper(url, protocol=protocol, **kw)), dev

        yield make


@pytest.mark.parametrize("protocol", [2, 1])
def test_gripper_reaches_stalls_on_object_and_satisfies_the_protocol(gripper_factory, protocol: int) -> None:
    g, dev = gripper_factory(protocol)
    assert isinstance(g, Gripper)
    assert g.lifecycle == Lifecycle.CONNECTED and not g.state().active
    with pytest.raises(NotConnected, match="activate"):
        g.gripper_go(0.05, 0.3)
    g.activate()
    assert g.gripper_go(0.08, 0.3) == GripperOutcome.REACHED
    assert abs(g.state().opening_m - 0.08) <= g.position_tolerance_m
    assert g.gripper_go(0.0, 0.3) == GripperOutcome.STALLED
    st = g.state()
    assert 0.0 < st.opening_m < 0.040  # squeezing the 40 mm object
    assert st.current_a < 0  # closing
    assert st.effort_frac == pytest.approx(0.3, abs=0.03)  # the current saturates at the goal current


def test_gripper_effort_sets_the_squeeze(gripper_factory) -> None:
    g, dev = gripper_factory()
    g.activate()
    g.gripper_go(0.0, 0.1)
    soft = g.state().opening_m
    g.gripper_go(0.0, 0.4)
    hard = g.state().opening_m
    assert hard < soft < 0.040


def test_gripper_non_blocking_and_timeout(gripper_factory) -> None:
    g, dev = gripper_factory(width_mm=None)
    g.activate()
    assert g.gripper_go(0.01, 0.3, blocking=False) == GripperOutcome.MOVING
    assert g.gripper_go(0.09, 0.3, timeout_s=0.0) == GripperOutcome.TIMEOUT


def test_gripper_bad_arguments(gripper_factory) -> None:
    g, dev = gripper_factory(width_mm=None)
    g.activate()
    with pytest.raises(LimitError, match="opening_m=0.5"):
        g.gripper_go(0.5, 0.3)
    with pytest.raises(ValueError, match="effort"):
        g.gripper_go(0.05, 1.5)
    with pytest.raises(ValueError, match="effort"):
        g.gripper_go(0.05, float("nan"))
    with pytest.raises(LimitError, match=r"opening_frac=-0.1 is outside \[0, 1\]"):
        g.gripper_go_frac(-0.1, 0.3)


@pytest.mark.parametrize("protocol", [2, 1])
def test_sustained_stall_latches_overload_reads_work_reboot_recovers(gripper_factory, protocol: int) -> None:
    g, dev = gripper_factory(protocol)
    g.activate()
    assert g.gripper_go(0.0, 1.0) == GripperOutcome.STALLED
    g.clock.sleep(3.0)  # hold the stall at full current
    st = g.state()  # reads stay allowed
    assert st.hardware_error & de.HW_OVERLOAD and not st.active
    assert g.lifecycle == Lifecycle.FAULT
    with pytest.raises(DeviceFault) as info:
        g.gripper_go(0.05, 0.3)
    assert "Overload" in str(info.value) and info.value.code & de.HW_OVERLOAD
    with pytest.raises(DeviceFault):
        g.activate()
    g.reboot()
    assert g.lifecycle == Lifecycle.CONNECTED and g.state().hardware_error == 0
    held = g.state().opening_m
    g.activate(0.05)
    # re-activation starts from the measured position: no jump
    goal = g.bus.read(1, "Goal Position")
    assert abs(goal - g.goal_ticks(held)) <= 2
    assert g.gripper_go(0.07, 0.3) == GripperOutcome.REACHED


def test_overheating_latches_under_a_moderate_sustained_squeeze() -> None:
    plant = Fingers(object_width_m=0.04)
    dev = make_bus(ids=[1], timing=False, plants={1: plant})
    servo = dev.servo(1)
    with serve_in_process(dev) as url, DynamixelGripper(url) as g:
        g.activate()
        assert g.gripper_go(0.0, 0.5) == GripperOutcome.STALLED  # 3.3 A: below the overload level
        g.clock.sleep(10.0)
        assert g.state().hardware_error == 0  # still warming up
        g.clock.sleep(30.0)
        assert g.state().hardware_error == de.HW_OVERHEATING
        assert servo.item("Torque Enable") == 0 and plant.current_a == 0.0  # torque off: cooling


def test_fault_during_a_move_ends_it_with_fault() -> None:
    plant = Fingers(object_width_m=0.04)
    dev = make_bus(ids=[1], timing=False, plants={1: plant})
    with serve_in_process(dev) as url, DynamixelGripper(url) as g:
        g.activate()
        plant.temperature_c = 79.9  # a motor already hot from earlier grasps
        assert g.gripper_go(0.0, 1.0) == GripperOutcome.FAULT
        assert g.lifecycle == Lifecycle.FAULT


def test_calibration_finds_the_stops_of_the_plant(gripper_factory) -> None:
    g, dev = gripper_factory(width_mm=None)
    plant = dev.servo(1).plant
    cal = g.calibrate(effort=0.2, max_opening_m=0.1)
    assert abs(cal.closed_ticks - plant.closed_ticks) < 15
    assert abs(cal.open_ticks - plant.open_ticks) < 15
    assert GripperCalibration.from_dict(cal.to_dict()) == cal
    assert g.gripper_go(0.05, 0.3) == GripperOutcome.REACHED
    assert plant.opening_m() == pytest.approx(0.05, abs=0.003)


def test_calibration_errors() -> None:
    with pytest.raises(ValueError, match="no range"):
        GripperCalibration(100, 100)
    with pytest.raises(ValueError, match="invalid"):
        GripperCalibration.from_dict({"closed_ticks": 1})


def test_wrong_model_is_refused() -> None:
    dev = make_bus(protocol=2, ids=[1], timing=False)
    dev.servo(1).mem[0:2] = (1030).to_bytes(2, "little")  # an XM430 answering
    with serve_in_process(dev) as url:
        with pytest.raises(NotConnected, match="1030"):
            DynamixelGripper(url)


def test_every_error_is_a_rig_error() -> None:
    for cls in (CommandRejected, DeviceFault, DeviceTimeout, LinkCorrupt, LimitError, NotConnected):
        assert issubclass(cls, RigError)


def test_cut_off_status_is_link_corrupt_and_the_bus_recovers() -> None:
    with serve_in_process(make_bus(ids=[1], timing=True)) as url:
        with DynamixelBus(f"rigfault://{url}#stall_after=5") as bus:
            with pytest.raises(LinkCorrupt, match="cut-off"):
                bus.read(1, "Model Number")  # 5 bytes of the status, then silence
            bus.port.ser.faults.stall_after = None
            assert bus.read(1, "Model Number") == 311


def test_one_bus_shared_by_threads_serializes_transactions(bus2) -> None:
    import threading

    bus, dev = bus2
    errors: list[BaseException] = []

    def worker(i: int) -> None:
        try:
            for k in range(40):
                bus.write(i, "LED", k % 2)
                assert bus.read(i, "Model Number") == 311
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(i,)) for i in (1, 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert not [t for t in threads if t.is_alive()]  # a deadlock must fail, not pass with no errors
    assert not errors
    assert [dev.servo(i).item("LED") for i in (1, 2)] == [1, 1]  # every thread's last write landed


def test_measured_opening_slightly_outside_the_range_is_clamped(gripper_factory) -> None:
    g, dev = gripper_factory(width_mm=None)
    cal = g.calibration
    assert g.goal_ticks(-0.5 * g.position_tolerance_m) == cal.closed_ticks
    assert g.goal_ticks(cal.max_opening_m + 0.5 * g.position_tolerance_m) == cal.open_ticks
    with pytest.raises(LimitError):
        g.goal_ticks(-2 * g.position_tolerance_m)


def test_debug_logs_every_dynamixel_byte(caplog):
    with caplog.at_level(logging.DEBUG, logger="tactile_rig.transport"):
        with DynamixelGripper("rigsim://dynamixel?ids=1") as g:
            g.state()
    tx = [r.getMessage() for r in caplog.records if " TX " in r.getMessage()]
    rx = [r.getMessage() for r in caplog.records if " RX " in r.getMessage()]
    assert any(m.endswith("TX ff ff fd 00 01 03 00 01 19 4e") for m in tx)  # the ping, byte for byte
    assert rx and all("dynamixel@rigsim://dynamixel?ids=1" in m for m in tx + rx)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="tactile_rig.transport"):
        with DynamixelGripper("rigsim://dynamixel?ids=1") as g:
            g.state()
    assert not [r for r in caplog.records if " TX " in r.getMessage()]  # nothing wrapped, nothing logged
