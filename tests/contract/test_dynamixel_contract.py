"""Contract of the Dynamixel MX-64 driver: identity, read/write, limits, error mapping, reconnect.

Runs in process, over a pty against the mock in another process, and on a real servo (--hw-bench).
"""

from __future__ import annotations

import pytest

from tactile_rig.core.errors import CommandRejected, DeviceTimeout, LimitError, NotConnected, RigError
from tactile_rig.devices.dynamixel.control_table import TABLES
from tactile_rig.drivers.dynamixel import DynamixelBus

pytestmark = pytest.mark.pty


def _bus(ep) -> DynamixelBus:
    return DynamixelBus(ep.port, baudrate=ep.baud, protocol=int(ep.options["protocol"]))


def test_identity_is_an_mx64_of_the_protocol_asked(servo) -> None:
    table = TABLES[servo.options["protocol"]]
    with _bus(servo) as bus:
        assert bus.ping(1) == table.model_number
        assert bus.read(1, "Model Number") == table.model_number
        assert bus.read(1, "ID") == 1


def test_a_written_value_reads_back(servo) -> None:
    with _bus(servo) as bus:
        bus.write(1, "Torque Enable", 0)
        present = bus.read(1, "Present Position")
        goal = max(0, min(4095, present + 7))
        bus.write(1, "Goal Position", goal)
        assert bus.read(1, "Goal Position") == goal
        bus.write(1, "Goal Position", present)


def test_out_of_range_and_read_only_writes_are_refused_before_the_wire(servo) -> None:
    with _bus(servo) as bus:
        with pytest.raises(LimitError, match=r"Torque Enable=5 is outside \[0, 1\]"):
            bus.write(1, "Torque Enable", 5)
        with pytest.raises(LimitError, match="read-only"):
            bus.write(1, "Present Position", 0)
        assert bus.ping(1)  # the bus is still usable


def test_a_refused_command_is_command_rejected_and_the_bus_keeps_working(servo) -> None:
    """What the firmware refuses: a goal beyond the position limits (Protocol 2.0: Data Limit
    Error), an EEPROM item while torque is on (Access Error), or a raw value beyond the item's range
    on Protocol 1.0 (Range Error)."""
    with _bus(servo) as bus:
        if servo.options["protocol"] == 2:
            with pytest.raises(CommandRejected) as info:
                bus.write(1, "Goal Position", bus.read(1, "Max Position Limit") + 1000)
            assert info.value.code == 6 and "Data Limit Error" in str(info.value)
            bus.write(1, "Torque Enable", 1)
            try:
                item = bus.table["Return Delay Time"]
                with pytest.raises(CommandRejected) as info:
                    bus.write_bytes(1, item.address, bytes([10]))
                assert info.value.code == 7 and "Access Error" in str(info.value)
            finally:
                bus.write(1, "Torque Enable", 0)
        else:
            item = bus.table["Goal Position"]
            with pytest.raises(CommandRejected) as info:
                bus.write_bytes(1, item.address, (5000).to_bytes(2, "little"))
            assert "Range Error" in str(info.value)
        assert bus.ping(1)


def test_an_absent_id_times_out_naming_it(servo) -> None:
    with _bus(servo) as bus:
        with pytest.raises(DeviceTimeout) as info:
            bus.ping(77)
        assert "dynamixel[77]" in str(info.value)
        assert bus.ping(1)


def test_closing_and_reopening_gives_the_same_device(servo) -> None:
    with _bus(servo) as bus:
        model = bus.ping(1)
    with pytest.raises(RigError):
        bus.ping(1)
    with _bus(servo) as bus:
        assert bus.ping(1) == model


def test_a_port_that_does_not_exist_is_not_connected() -> None:
    with pytest.raises(NotConnected, match="/dev/ttyNOPE"):
        DynamixelBus("/dev/ttyNOPE", baudrate=57600, protocol=2)
