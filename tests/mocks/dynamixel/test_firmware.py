"""The MX-64 firmware mock on its own codec: instructions, access rules, timing, plant, scene."""

from __future__ import annotations

import pytest
from hypothesis import given, strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper
from tactile_rig.control.protocols import GripperOutcome
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.dynamixel.codec import Packet, StreamParser, encode_p1, encode_p2
from tactile_rig.mocks.registry import Params, create_device

BYTE_S = 10 / 1_000_000


def exchange(dev, wire: bytes, t_s: float = 0.0, protocol: int = 2) -> tuple[list[Packet], float]:
    """Feed ``wire`` at ``t_s``; return the status packets and when the last byte arrived."""
    dev.feed(wire, t_s)
    last = dev.next_ready_s()
    out = b""
    while dev.pending_output():
        last = dev.next_ready_s(replies_only=True)
        out += dev.pop_ready(last)
    return StreamParser(protocol, status=True).feed(out), (t_s if last is None else last)


def p2(dxl_id: int, inst: int, params: str = "") -> bytes:
    return encode_p2(dxl_id, inst, bytes.fromhex(params))


def test_broadcast_ping_answers_in_id_order_each_after_the_previous() -> None:
    dev = make_bus(ids=[3, 1, 2], return_delay_us=20)
    replies, t_end = exchange(dev, p2(0xFE, 0x01))
    assert [r.id for r in replies] == [1, 2, 3]
    assert all(r.params == bytes([311 & 0xFF, 311 >> 8, 45]) for r in replies)
    # 10 bytes in, then three (20 us delay + 14 bytes) status packets back to back
    assert t_end == pytest.approx(10 * BYTE_S + 3 * (20e-6 + 14 * BYTE_S), abs=1e-12)


def test_broadcast_write_applies_to_all_without_status_and_read_levels() -> None:
    dev = make_bus(ids=[1, 2], timing=False)
    replies, _ = exchange(dev, p2(0xFE, 0x03, "41 00 01"))  # LED on, broadcast
    assert replies == [] and all(dev.servo(i).item("LED") == 1 for i in (1, 2))
    replies, _ = exchange(dev, p2(1, 0x03, "44 00 01"))  # Status Return Level 1
    assert replies == []  # the answer to that very write is already suppressed
    assert exchange(dev, p2(1, 0x03, "41 00 00"))[0] == []
    assert exchange(dev, p2(1, 0x02, "41 00 01 00"))[0] == [Packet(2, 1, 0x55, b"\x00", 0)]


def test_access_length_and_instruction_errors() -> None:
    dev = make_bus(ids=[1], timing=False)
    cases = [
        (p2(1, 0x03, "00 00 01 00"), de.ACCESS_ERROR),  # Model Number is read-only
        (p2(1, 0x03, "0E 00 01"), de.ACCESS_ERROR),  # address 14: no item
        (p2(1, 0x03, "74 00 01 02"), de.DATA_LENGTH),  # two bytes of the 4-byte Goal Position
        (p2(1, 0x03, "0B 00 02"), de.DATA_RANGE),  # Operating Mode 2 does not exist
        (p2(1, 0x02, "84 00"), de.DATA_LENGTH),  # Read without a length
        (p2(1, 0x02, "90 02 10 00"), de.ACCESS_ERROR),  # beyond the table
        (p2(1, 0x7E), de.INSTRUCTION_ERROR),
        (p2(1, 0x06, "05"), de.DATA_RANGE),  # unknown factory reset option
    ]
    for wire, err in cases:
        replies, _ = exchange(dev, wire)
        assert [r.error for r in replies] == [err], wire.hex(" ")


def test_eeprom_is_locked_while_torque_is_on() -> None:
    dev = make_bus(ids=[1], timing=False)
    assert exchange(dev, p2(1, 0x03, "40 00 01"))[0][0].error == 0
    assert exchange(dev, p2(1, 0x03, "09 00 00"))[0][0].error == de.ACCESS_ERROR
    assert dev.servo(1).item("Return Delay Time") == 250
    assert exchange(dev, p2(1, 0x03, "40 00 00"))[0][0].error == 0
    assert exchange(dev, p2(1, 0x03, "09 00 00"))[0][0].error == 0


def test_indirect_address_maps_present_position() -> None:
    dev = make_bus(ids=[1], timing=False)
    servo = dev.servo(1)
    exchange(dev, p2(1, 0x03, "A8 00 84 00 85 00"))  # Indirect Address 1, 2 = 132, 133
    replies, _ = exchange(dev, p2(1, 0x02, "E0 00 02 00"))  # Indirect Data 1-2
    assert int.from_bytes(replies[0].params, "little") == servo.item("Present Position")


def test_operating_mode_change_resets_profile_and_goal_current() -> None:
    dev = make_bus(ids=[1], timing=False)
    servo = dev.servo(1)
    exchange(dev, p2(1, 0x03, "70 00 64 00 00 00"))  # Profile Velocity 100
    exchange(dev, p2(1, 0x03, "26 00 F4 01"))  # Current Limit 500
    exchange(dev, p2(1, 0x03, "0B 00 05"))  # current-based position
    assert servo.item("Profile Velocity") == 0 and servo.item("Goal Current") == 500


def test_factory_reset_all_moves_the_line_to_57600_and_broadcast_all_is_ignored() -> None:
    dev = make_bus(ids=[4], timing=False)
    assert exchange(dev, p2(0xFE, 0x06, "FF"))[0] == []
    assert dev.servo(4) is not None and dev.baud == 1_000_000
    replies, t = exchange(dev, p2(4, 0x06, "FF"))
    assert replies[0].id == 4 and replies[0].error == 0  # the answer comes before the reset
    assert dev.servo(1) is not None and dev.baud == 57600


def test_a_client_at_the_wrong_baud_gets_garbage_not_a_status() -> None:
    dev = make_bus(ids=[1])
    dev.set_client_baud(57600)
    replies, _ = exchange(dev, p2(1, 0x01))
    assert not [r for r in replies if isinstance(r, Packet)]


def test_protocol1_firmware_errors() -> None:
    dev = make_bus(protocol=1, ids=[1], timing=False)

    def p1(inst: int, params: str = "") -> int:
        replies, _ = exchange(dev, encode_p1(1, inst, bytes.fromhex(params)), protocol=1)
        return replies[0].error

    assert p1(0x01) == 0
    assert p1(0x03, "06 00 04 00 08") == 0  # angle limits 1024 .. 2048
    assert p1(0x03, "1E 00 0C") == de.P1_ANGLE_LIMIT  # goal 3072 outside them
    assert p1(0x03, "22 FF 07") == de.P1_RANGE  # Torque Limit 2047 > 1023
    assert p1(0x55) == de.P1_INSTRUCTION
    bad = bytearray(encode_p1(1, 0x02, bytes.fromhex("2B 01")))
    bad[-1] ^= 0x10
    assert exchange(dev, bytes(bad), protocol=1)[0][0].error == de.P1_CHECKSUM


def test_protocol1_shutdown_drops_torque_limit_and_sets_error_bits() -> None:
    dev = make_bus(protocol=1, ids=[1], timing=False)
    servo = dev.servo(1)
    servo.inject_hardware_error(de.P1_OVERLOAD)
    replies, _ = exchange(dev, encode_p1(1, 0x02, bytes.fromhex("22 02")), protocol=1)
    assert replies[0].error == de.P1_OVERLOAD and replies[0].params == b"\x00\x00"
    exchange(dev, encode_p1(1, 0x08), protocol=1)
    assert servo.latched == 0 and servo.item("Torque Limit") == 1023


def test_factory_parameters_are_checked() -> None:
    clock = VirtualClock()
    with pytest.raises(ValueError, match="unknown parameter"):
        create_device("dynamixel", Params({"protocl": "2"}, source="t"), clock=clock)
    with pytest.raises(ValueError, match="Protocol 1"):
        create_device("dynamixel", Params({"model": "310", "protocol": "2"}, source="t"), clock=clock)
    with pytest.raises(ValueError, match="id=300"):
        create_device("dynamixel", Params({"ids": "300"}, source="t"), clock=clock)
    dev = create_device("dynamixel", Params({"protocol": "1", "ids": "1,5"}, source="t"), clock=clock)
    assert dev.describe() == {"protocol": 1, "ids": [1, 5], "model": 310} and dev.baud == 57600


def test_scene_fingers_model_is_the_plant(tmp_path) -> None:
    scene = tmp_path / "grip.toml"
    scene.write_text('[scene]\nname = "grip"\n[models.fingers]\ntype = "fingers"\nobject_width_m = 0.03\nobject_stiffness_npm = 20000.0\n')
    with DynamixelGripper(f"rigsim://dynamixel?scene={scene}&timing=0") as g:
        g.activate()
        assert g.gripper_go(0.0, 0.2) == GripperOutcome.STALLED
        assert 0.025 < g.state().opening_m < 0.03  # 1.3 A x 40 N/A squeezes 20 kN/m by 2.6 mm


def test_homing_offset_shifts_present_and_goal_positions() -> None:
    dev = make_bus(ids=[1], timing=False)
    servo = dev.servo(1)
    shaft = servo.plant.position_ticks
    exchange(dev, p2(1, 0x03, "14 00 E8 03 00 00"))  # Homing Offset 1000
    replies, _ = exchange(dev, p2(1, 0x02, "84 00 04 00"))
    assert int.from_bytes(replies[0].params, "little") == round(shaft) + 1000
    exchange(dev, p2(1, 0x03, "74 00 B8 0B 00 00"))  # Goal Position 3000 (offset frame)
    exchange(dev, p2(1, 0x03, "40 00 01"))
    dev.advance_to(1.0)
    assert servo.plant.position_ticks == pytest.approx(2000)


@given(st.data())
def test_device_answers_every_packet_of_a_stream_split_anywhere(data) -> None:
    from tactile_rig.testing.strategies import split_stream

    dev = make_bus(ids=[1, 2], timing=False)
    reqs = data.draw(st.lists(st.tuples(st.sampled_from([1, 2]), st.sampled_from(["ping", "read"])),
                              min_size=1, max_size=5))
    wires = [p2(i, 0x01) if kind == "ping" else p2(i, 0x02, "00 00 02 00") for i, kind in reqs]
    noise = st.binary(max_size=5).map(lambda b: b.replace(b"\xff", b"\x00"))
    stream = b"".join(data.draw(noise) + w for w in wires)
    for chunk in data.draw(split_stream(stream)):
        dev.feed(chunk, 0.0)
    replies = StreamParser(2, status=True).feed(dev.pop_ready(0.0))
    assert [(r.id, r.error) for r in replies] == [(i, 0) for i, _ in reqs]
    assert all(r.params[:2] == bytes([311 & 0xFF, 311 >> 8]) for r in replies)
