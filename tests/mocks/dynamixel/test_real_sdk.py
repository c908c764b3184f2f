"""The real dynamixel-sdk drives the MX-64 mock: in process (virtual time) and over a pty."""

from __future__ import annotations

import importlib
import time
from contextlib import contextmanager
from importlib.metadata import version

import pytest
import dynamixel_sdk as sdk

from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.drivers.dynamixel.bus import UrlPortHandler
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.testing import serve_in_process, serve_on_pty

OK = sdk.COMM_SUCCESS
# dynamixel_easy_sdk ships with dynamixel-sdk 4 and later (what CI installs): there it must import;
# the declared floor, dynamixel-sdk 3.8, has no easy SDK
SDK_VERSION = version("dynamixel-sdk")
easy = importlib.import_module("dynamixel_easy_sdk") if int(SDK_VERSION.split(".")[0]) >= 4 else None

# Values that respect the cross-item limits when items are written in address order.
P2_VALUES = {"Operating Mode": 5, "Temperature Limit": 70, "Max Position Limit": 4000, "Min Position Limit": 100,
             "Goal Position": 1500, "Protocol Type": 2, "Torque Enable": 1}
P1_VALUES = {"Temperature Limit": 70, "CW Angle Limit": 100, "CCW Angle Limit": 4000, "Goal Position": 2000,
             "Torque Ctrl Mode Enable": 1, "Torque Enable": 1, "Lock": 0}
SKIP = {"ID", "Baud Rate", "Status Return Level"}  # change how the servo answers: tested on their own


def _value(it: ct.Item, special: dict[str, int]) -> int:
    if it.name in special:
        return special[it.name]
    v = it.low + (it.high - it.low) // 3
    return v if v != it.default else v + 1


def _sdk_port(url: str, baud: int) -> UrlPortHandler:
    port = UrlPortHandler(url)
    assert port.openPort() and port.setBaudRate(baud)
    return port


def _rw(ph, port, dxl_id: int, it: ct.Item, value: int | None = None):
    if value is None:
        data, res, err = ph.readTxRx(port, dxl_id, it.address, it.size)
        return it.from_raw(int.from_bytes(bytes(data), "little")), res, err
    res, err = ph.writeTxRx(port, dxl_id, it.address, it.size, list(it.to_raw(value).to_bytes(it.size, "little")))
    return None, res, err


@contextmanager
def _served(bus, transport: str):
    """An open SDK port on ``bus``: in process (URL) or over a pty (plain PortHandler)."""
    if transport == "pty":
        with serve_on_pty(bus) as server:
            port = sdk.PortHandler(server.port)
            assert port.openPort() and port.setBaudRate(bus.baud)
            yield port
            port.closePort()
    else:
        with serve_in_process(bus) as url:
            port = _sdk_port(url, bus.baud)
            yield port
            port.closePort()


@pytest.mark.parametrize("protocol,transport", [
    (2, "in-process"), (1, "in-process"), pytest.param(2, "pty", marks=pytest.mark.pty)])
def test_sdk_reads_and_writes_every_control_table_item(protocol: int, transport: str) -> None:
    bus = make_bus(protocol=protocol, ids=[1], timing=transport == "pty", return_delay_us=0)
    servo = bus.servo(1)
    table = ct.TABLES[protocol]
    special = P2_VALUES if protocol == 2 else P1_VALUES
    with _served(bus, transport) as port:
        ph = sdk.PacketHandler(float(protocol))
        model, res, err = ph.ping(port, 1)
        assert (model, res, err) == (table.model_number, OK, 0)
        torque = table["Torque Enable"]
        for it in [i for i in table if i is not torque] + [torque]:  # torque last: it locks EEPROM
            if it.name in SKIP:
                continue
            if it.writable:
                value = _value(it, special)
                _, res, err = _rw(ph, port, 1, it, value)
                assert (res, err) == (OK, 0), f"write {it.name}={value}: {res}, {err}"
                got, res, err = _rw(ph, port, 1, it)
                assert (got, res, err) == (value, OK, 0), it.name
            else:
                got, res, err = _rw(ph, port, 1, it)
                assert (res, err) == (OK, 0), it.name
                if not (it.name == "Realtime Tick" and transport == "pty"):  # real time moves on
                    assert got == servo.item(it.name), it.name


def test_sync_read_fast_sync_read_bulk_read_and_group_writes_over_several_ids() -> None:
    bus = make_bus(ids=[1, 2, 3], timing=True, return_delay_us=0)
    with serve_in_process(bus) as url:
        port = _sdk_port(url, bus.baud)
        ph = sdk.PacketHandler(2.0)
        goals = {1: 1100, 2: 2100, 3: 3100}
        sw = sdk.GroupSyncWrite(port, ph, 116, 4)
        for i, g in goals.items():
            assert sw.addParam(i, list(g.to_bytes(4, "little")))
        assert sw.txPacket() == OK
        bw = sdk.GroupBulkWrite(port, ph)
        for i in goals:
            assert bw.addParam(i, 65, 1, [1])  # LED on
        assert bw.txPacket() == OK
        for i in goals:
            assert bus.servo(i).item("Goal Position") == goals[i]
            assert bus.servo(i).item("LED") == 1
        sr = sdk.GroupSyncRead(port, ph, 116, 4)
        for i in goals:
            sr.addParam(i)
        assert sr.txRxPacket() == OK
        assert {i: sr.getData(i, 116, 4) for i in goals} == goals
        assert sr.fastSyncRead() == OK
        assert {i: sr.getData(i, 116, 4) for i in goals} == goals
        br = sdk.GroupBulkRead(port, ph)
        assert br.addParam(1, 0, 2) and br.addParam(2, 116, 4) and br.addParam(3, 65, 1)
        assert br.txRxPacket() == OK
        assert (br.getData(1, 0, 2), br.getData(2, 116, 4), br.getData(3, 65, 1)) == (311, 2100, 1)
        assert br.fastBulkRead() == OK
        assert (br.getData(1, 0, 2), br.getData(2, 116, 4), br.getData(3, 65, 1)) == (311, 2100, 1)


def test_p1_bulk_read_and_sync_write() -> None:
    bus = make_bus(protocol=1, ids=[1, 2], timing=True)
    with serve_in_process(bus) as url:
        port = _sdk_port(url, 57600)
        ph = sdk.PacketHandler(1.0)
        sw = sdk.GroupSyncWrite(port, ph, 30, 2)
        assert sw.addParam(1, [0x10, 0x04]) and sw.addParam(2, [0x20, 0x08])
        assert sw.txPacket() == OK
        # GroupBulkRead of SDK 4.1.0 passes a fast_option the Protocol 1.0 handler does not take,
        # so Protocol 1.0 bulk read goes through the handler (as DynamixelBus.bulk_read does).
        param = [2, 1, 30, 2, 2, 0]  # [length, ID, address] per servo
        assert ph.bulkReadTx(port, param, len(param)) == OK
        assert ph.readRx(port, 1, 2) == ([0x10, 0x04], OK, 0)
        assert ph.readRx(port, 2, 2) == ([310 & 0xFF, 310 >> 8], OK, 0)
        assert bus.servo(2).item("Goal Position") == 0x0820


def test_reg_write_action_factory_reset_and_status_return_level() -> None:
    bus = make_bus(ids=[1], timing=False)
    servo = bus.servo(1)
    with serve_in_process(bus) as url:
        port = _sdk_port(url, bus.baud)
        ph = sdk.PacketHandler(2.0)
        assert ph.regWriteTxRx(port, 1, 65, 1, [1]) == (OK, 0)
        assert servo.item("LED") == 0 and servo.item("Registered Instruction") == 1
        assert ph.action(port, 1) == OK  # the SDK does not wait for the Action's status
        assert servo.item("LED") == 1 and servo.item("Registered Instruction") == 0
        assert ph.action(port, 1) == OK  # nothing registered: the status says Instruction Error
        port.setPacketTimeout(11)
        status, res = ph.rxPacket(port, False)
        assert (res, status[8]) == (OK, de.INSTRUCTION_ERROR)
        assert ph.write1ByteTxRx(port, 1, 9, 7) == (OK, 0)
        assert ph.factoryReset(port, 1, 0x02) == (OK, 0)
        port.ser.clock.advance(0.1)  # the servo boots
        assert ph.read1ByteTxRx(port, 1, 9) == (250, OK, 0)  # Return Delay Time back to default
        assert ph.write1ByteTxOnly(port, 1, 68, 0) == OK  # Status Return Level 0: ping only
        assert ph.read1ByteTxRx(port, 1, 65)[1] == sdk.COMM_RX_TIMEOUT
        assert ph.ping(port, 1) == (311, OK, 0)


def test_id_and_baud_changes_take_effect_after_the_status() -> None:
    bus = make_bus(ids=[1], timing=True)
    with serve_in_process(bus) as url:
        port = _sdk_port(url, 1_000_000)
        ph = sdk.PacketHandler(2.0)
        assert ph.write1ByteTxRx(port, 1, 7, 9) == (OK, 0)
        assert ph.ping(port, 9) == (311, OK, 0)
        assert ph.write1ByteTxRx(port, 9, 8, 1) == (OK, 0)  # 57600 bps
        assert ph.ping(port, 9)[1] != OK  # the host is still at 1 Mbps
        assert port.setBaudRate(57600)
        assert ph.ping(port, 9) == (311, OK, 0)


def test_latched_fault_sets_alert_on_every_status_until_reboot() -> None:
    bus = make_bus(ids=[1], timing=False)
    servo = bus.servo(1)
    with serve_in_process(bus) as url:
        port = _sdk_port(url, bus.baud)
        ph = sdk.PacketHandler(2.0)
        assert ph.write1ByteTxRx(port, 1, 64, 1) == (OK, 0)
        servo.inject_hardware_error(de.HW_OVERHEATING)
        assert ph.read1ByteTxRx(port, 1, 70) == (de.HW_OVERHEATING, OK, de.ALERT_BIT)
        assert ph.read1ByteTxRx(port, 1, 64) == (0, OK, de.ALERT_BIT)  # torque went off
        assert ph.write1ByteTxRx(port, 1, 64, 1) == (OK, de.ALERT_BIT)
        assert ph.read1ByteTxRx(port, 1, 64)[0] == 0  # and stays off
        assert ph.reboot(port, 1) == (OK, de.ALERT_BIT)  # the status precedes the reboot
        port.ser.clock.advance(0.1)
        assert ph.read1ByteTxRx(port, 1, 70) == (0, OK, 0)


def test_wire_time_and_return_delay_in_virtual_time() -> None:
    bus = make_bus(ids=[1], timing=True, return_delay_us=100)
    with serve_in_process(bus) as url:
        port = _sdk_port(url, 1_000_000)
        clock = port.ser.clock
        t0 = clock.now_s()
        assert ph_read(port) == OK
        # 14 bytes out, 100 us return delay, 15 bytes back, 10 us per byte at 1 Mbps
        assert clock.now_s() - t0 == pytest.approx(29e-5 + 100e-6, abs=1e-9)


def ph_read(port) -> int:
    return sdk.PacketHandler(2.0).read4ByteTxRx(port, 1, 132)[1]


@pytest.mark.pty
def test_classic_and_easy_sdk_over_a_pty() -> None:
    bus = make_bus(ids=[1, 2], return_delay_us=0)
    with serve_on_pty(bus) as server:
        port = sdk.PortHandler(server.port)
        assert port.openPort() and port.setBaudRate(1_000_000)
        ph = sdk.PacketHandler(2.0)
        assert ph.ping(port, 1) == (311, OK, 0)
        assert ph.ping(port, 7)[1] == sdk.COMM_RX_TIMEOUT
        assert ph.write4ByteTxRx(port, 2, 116, 2500) == (OK, 0)
        sr = sdk.GroupSyncRead(port, ph, 116, 4)
        sr.addParam(1), sr.addParam(2)
        assert sr.txRxPacket() == OK and sr.getData(2, 116, 4) == 2500
        br = sdk.GroupBulkRead(port, ph)
        assert br.addParam(1, 0, 2) and br.addParam(2, 116, 4)
        assert br.txRxPacket() == OK and (br.getData(1, 0, 2), br.getData(2, 116, 4)) == (311, 2500)
        port.closePort()

        if easy is None:
            pytest.skip(f"dynamixel-sdk {SDK_VERSION} has no dynamixel_easy_sdk (it ships with 4 and later)")
        Connector, DxlRuntimeError = easy.Connector, easy.DxlRuntimeError
        conn = Connector(server.port, 1_000_000)
        motor = conn.createMotor(1)  # pings, then reads Torque Enable and Operating Mode
        motor.LEDOn()
        assert motor.isLEDOn() == 1
        assert motor.getPresentPosition() == bus.servo(1).item("Present Position")
        bus.servo(1).inject_hardware_error(de.HW_OVERLOAD)
        # dynamixel_easy_sdk 4.1.0 bug: DxlError(0x80) is no enum member, so the Alert bit
        # surfaces as a bare ValueError instead of DxlRuntimeError (see docs/dynamixel.md).
        with pytest.raises(ValueError, match="128"):
            motor.isLEDOn()
        with pytest.raises(ValueError, match="128"):
            conn.reboot(1)  # the status precedes the reboot, so it still carries the Alert bit
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:  # wait out the 50 ms boot without asserting a time
            try:
                assert conn.read1ByteData(1, 70) == 0  # Hardware Error Status cleared
                break
            except DxlRuntimeError:
                time.sleep(0.01)
        else:
            pytest.fail("the servo did not come back after reboot")
        conn.closePort()
