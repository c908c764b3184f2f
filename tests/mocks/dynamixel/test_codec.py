"""The mock's own Dynamixel codec: e-manual golden bytes, round trips, and stream resync."""

from __future__ import annotations

import pytest
from dynamixel_sdk import Protocol2PacketHandler
from hypothesis import given, strategies as st

from tactile_rig.mocks.dynamixel.codec import (
    ChecksumFailure, Packet, StreamParser, crc16, decode, encode_p1, encode_p2, encode_p2_status, stuff, unstuff)
from tactile_rig.testing.strategies import interleaved, split_stream
from tactile_rig.testing.strategies_dynamixel import p1_instruction, p2_instruction, p2_status, stuffing_params

H = bytes.fromhex

# (what, bytes, decoded packet) from the ROBOTIS e-manual (protocol2.md / protocol1.md)
P2_INSTRUCTIONS = [
    ("ping", "FF FF FD 00 01 03 00 01 19 4E", Packet(2, 1, 0x01)),
    ("read 132/4", "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15", Packet(2, 1, 0x02, H("84 00 04 00"))),
    ("write 116=512", "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", Packet(2, 1, 0x03, H("74 00 00 02 00 00"))),
    ("sync read", "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA", Packet(2, 0xFE, 0x82, H("84 00 04 00 01 02"))),
    ("reboot", "FF FF FD 00 01 03 00 08 2F 4E", Packet(2, 1, 0x08)),
    ("action", "FF FF FD 00 01 03 00 05 02 CE", Packet(2, 1, 0x05)),
    ("factory reset", "FF FF FD 00 01 04 00 06 01 A1 E6", Packet(2, 1, 0x06, H("01"))),
]
P2_STATUS = [
    ("ping status", "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D", Packet(2, 1, 0x55, H("06 04 26"), error=0)),
    ("read status", "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0", Packet(2, 1, 0x55, H("A6 00 00 00"), error=0)),
    ("empty status", "FF FF FD 00 01 04 00 55 00 A1 0C", Packet(2, 1, 0x55, b"", error=0)),
]
P1_PACKETS = [
    ("ping", "FF FF 01 02 01 FB", Packet(1, 1, 0x01), False),
    ("ping status", "FF FF 01 02 00 FC", Packet(1, 1, 0x55, b"", error=0), True),
    ("read 43/1", "FF FF 01 04 02 2B 01 CC", Packet(1, 1, 0x02, H("2B 01")), False),
    ("read status", "FF FF 01 03 00 20 DB", Packet(1, 1, 0x55, H("20"), error=0), True),
    ("error status", "FF FF 01 02 24 D8", Packet(1, 1, 0x55, b"", error=0x24), True),
]


@pytest.mark.parametrize("what,hexbytes,pkt", P2_INSTRUCTIONS, ids=[c[0] for c in P2_INSTRUCTIONS])
def test_p2_golden_instructions_encode_and_decode(what: str, hexbytes: str, pkt: Packet) -> None:
    assert encode_p2(pkt.id, pkt.instruction, pkt.params) == H(hexbytes)
    assert decode(H(hexbytes), 2) == pkt


@pytest.mark.parametrize("what,hexbytes,pkt", P2_STATUS, ids=[c[0] for c in P2_STATUS])
def test_p2_golden_status_encode_and_decode(what: str, hexbytes: str, pkt: Packet) -> None:
    assert encode_p2_status(pkt.id, pkt.error, pkt.params) == H(hexbytes)
    assert decode(H(hexbytes), 2, status=True) == pkt


@pytest.mark.parametrize("what,hexbytes,pkt,status", P1_PACKETS, ids=[c[0] for c in P1_PACKETS])
def test_p1_golden_packets(what: str, hexbytes: str, pkt: Packet, status: bool) -> None:
    code = pkt.error if status else pkt.instruction
    assert encode_p1(pkt.id, code, pkt.params) == H(hexbytes)
    assert decode(H(hexbytes), 1, status=status) == pkt


@given(st.binary(max_size=64))
def test_crc_matches_the_sdk_table(data: bytes) -> None:
    # The SDK is only an oracle here: the mock's CRC is its own table-free-of-SDK implementation.
    assert crc16(data) == Protocol2PacketHandler().updateCRC(0, list(data), len(data))


def test_stuffing_example_from_the_manual() -> None:
    assert stuff(H("03 FF FF FD 01")) == H("03 FF FF FD FD 01")
    assert unstuff(H("03 FF FF FD FD 01")) == H("03 FF FF FD 01")


@given(p2_instruction())
def test_p2_instruction_round_trip_with_stuffing(pkt: Packet) -> None:
    wire = encode_p2(pkt.id, pkt.instruction, pkt.params)
    assert b"\xff\xff\xfd" not in wire[3:].replace(b"\xff\xff\xfd\xfd", b"")  # no false header inside
    assert decode(wire, 2) == pkt


@given(p2_status())
def test_p2_status_round_trip(pkt: Packet) -> None:
    assert decode(encode_p2_status(pkt.id, pkt.error, pkt.params), 2, status=True) == pkt


@pytest.mark.parametrize("inst", [0x03, 0xFF, 0xFD])
def test_header_bytes_at_every_boundary_round_trip(inst: int) -> None:
    base = bytes(range(1, 9))
    for frag in (b"\xff\xff\xfd", b"\xff\xff\xfd\xfd", b"\xff\xff", b"\xfd"):
        for k in range(len(base) + 1):
            params = base[:k] + frag + base[k:]
            assert decode(encode_p2(7, inst, params), 2) == Packet(2, 7, inst, params)
            assert decode(encode_p2_status(7, inst, params), 2, status=True) == Packet(2, 7, 0x55, params, inst)


@given(stuffing_params(40))
def test_unstuff_inverts_stuff(body: bytes) -> None:
    assert unstuff(stuff(body)) == body


@given(st.data())
def test_p2_stream_split_anywhere_with_garbage_yields_exactly_the_packets(data: st.DataObject) -> None:
    pkts = data.draw(st.lists(p2_instruction(12), min_size=1, max_size=4))
    wires = [encode_p2(p.id, p.instruction, p.params) for p in pkts]
    stream = data.draw(interleaved(wires, max_garbage=12))
    parser = StreamParser(2)
    got: list = []
    for chunk in data.draw(split_stream(stream)):
        got += parser.feed(chunk)
    assert [e for e in got if isinstance(e, Packet)] == pkts


@given(st.data())
def test_p1_stream_split_anywhere_yields_exactly_the_packets(data: st.DataObject) -> None:
    pkts = data.draw(st.lists(p1_instruction(8), min_size=1, max_size=4))
    wires = [encode_p1(p.id, p.instruction, p.params) for p in pkts]
    # P1 has no reserved byte and a 1-byte checksum, so a random FF FF in garbage forms a valid
    # packet 1 time in 256: garbage here is noise without 0xFF (a line between packets).
    noise = st.binary(max_size=6).map(lambda b: b.replace(b"\xff", b"\x00"))
    stream = b"".join(data.draw(noise) + w for w in wires) + data.draw(noise)
    parser = StreamParser(1)
    got: list = []
    for chunk in data.draw(split_stream(stream)):
        got += parser.feed(chunk)
    assert got == pkts


@given(p2_instruction(8), st.integers(1, 12))
def test_cut_off_packet_then_a_valid_one_resyncs(pkt: Packet, cut: int) -> None:
    wire = encode_p2(pkt.id, pkt.instruction, pkt.params)
    ping = encode_p2(1, 0x01)
    parser = StreamParser(2)
    events = parser.feed(wire[:max(1, len(wire) - cut)] + ping + ping)
    assert [e for e in events if isinstance(e, Packet)][-1] == Packet(2, 1, 0x01)


def test_corrupt_packet_is_reported_as_checksum_failure() -> None:
    bad = bytearray(encode_p2(3, 0x02, H("84 00 04 00")))
    bad[9] ^= 0x40
    assert StreamParser(2).feed(bytes(bad)) == [ChecksumFailure(2, 3, 0x02)]
    bad1 = bytearray(encode_p1(3, 0x02, H("2B 01")))
    bad1[5] ^= 1
    assert StreamParser(1).feed(bytes(bad1)) == [ChecksumFailure(1, 3, 0x02)]


@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    for proto in (1, 2):
        parser = StreamParser(proto)
        for e in parser.feed(data):
            assert isinstance(e, (Packet, ChecksumFailure))
