"""The mock's own wire codec for Dynamixel Protocol 2.0 and 1.0 (independent of dynamixel-sdk).

Protocol 2.0: ``FF FF FD 00 ID LEN_L LEN_H INST params CRC_L CRC_H``; LEN counts instruction,
params and CRC; CRC-16 (poly 0x8005, init 0, not reflected) over everything before it, computed on
the *stuffed* packet (``FF FF FD`` in the instruction/params becomes ``FF FF FD FD``).
Protocol 1.0: ``FF FF ID LEN INST params CHK``; LEN = params + 2; CHK = ~(ID+LEN+INST+params).

:class:`StreamParser` turns an arbitrary byte stream (split anywhere, garbage between packets,
cut-off packets) into packets and checksum failures, resynchronising one byte at a time like the
firmware does.

Headers, IDs and instruction codes are :mod:`tactile_rig.devices.dynamixel.packets`, shared with
the driver. The codec itself is not shared: the driver's (:mod:`tactile_rig.drivers.dynamixel.wire`)
is written separately on purpose, so a bug in one cannot hide in the other.
"""

from __future__ import annotations

from dataclasses import dataclass

from tactile_rig.devices.dynamixel.packets import (
    BROADCAST_ID,
    CRC16_POLY,
    P1_HEADER,
    P2_HEADER,
    P2_RESERVED,
    STATUS_INSTRUCTION,
)

__all__ = [
    "BROADCAST_ID", "ChecksumFailure", "MAX_PACKET_LEN", "P1_HEADER", "P2_HEADER", "Packet", "STATUS", "StreamParser",
    "checksum_p1", "crc16", "decode", "encode_p1", "encode_p2", "encode_p2_status", "stuff", "unstuff",
]

STATUS = STATUS_INSTRUCTION
#: the firmware's receive buffer: longer declared lengths are noise, not packets
MAX_PACKET_LEN = 1024


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC16_POLY) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """Dynamixel Protocol 2.0 CRC-16 of ``data`` (continuing from ``crc``)."""
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert a 0xFD after every ``FF FF FD`` in instruction+params."""
    out = bytearray()
    i = 0
    n = len(body)
    while i < n:
        out.append(body[i])
        if body[i] == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF:
            out.append(0xFD)
        i += 1
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the 0xFD inserted after every ``FF FF FD``."""
    out = bytearray()
    i = 0
    n = len(body)
    while i < n:
        out.append(body[i])
        if (body[i] == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF
                and i + 1 < n and body[i + 1] == 0xFD):
            i += 1
        i += 1
    return bytes(out)


def checksum_p1(body: bytes) -> int:
    """Protocol 1.0 checksum of ID, LEN, INST/ERR and params."""
    return (~sum(body)) & 0xFF


@dataclass(frozen=True)
class Packet:
    """A decoded packet: instruction (or 0x55 status with ``error``) and unstuffed params."""

    protocol: int
    id: int
    instruction: int
    params: bytes = b""
    error: int = 0  # status packets only


@dataclass(frozen=True)
class ChecksumFailure:
    """A complete packet whose CRC/checksum did not match (the firmware answers CRC Error)."""

    protocol: int
    id: int
    instruction: int


def encode_p2(dxl_id: int, instruction: int, params: bytes = b"", *, error: int | None = None) -> bytes:
    """Encode a Protocol 2.0 instruction packet, or a status packet when ``error`` is given."""
    body = bytes([instruction]) + (bytes([error]) if error is not None else b"") + bytes(params)
    body = stuff(body)
    length = len(body) + 2
    pkt = P2_HEADER + bytes([P2_RESERVED, dxl_id, length & 0xFF, length >> 8]) + body
    crc = crc16(pkt)
    return pkt + bytes([crc & 0xFF, crc >> 8])


def encode_p2_status(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    return encode_p2(dxl_id, STATUS, params, error=error)


def encode_p1(dxl_id: int, instruction_or_error: int, params: bytes = b"") -> bytes:
    """Encode a Protocol 1.0 packet (instruction, or status with the error byte in its place)."""
    body = bytes([dxl_id, len(params) + 2, instruction_or_error]) + bytes(params)
    return P1_HEADER + body + bytes([checksum_p1(body)])


def decode(packet: bytes, protocol: int, *, status: bool = False) -> Packet:
    """Decode one complete packet; ValueError names what is wrong."""
    parser = StreamParser(protocol, status=status)
    events = parser.feed(packet)
    if len(events) != 1 or not isinstance(events[0], Packet) or parser.pending:
        raise ValueError(f"not exactly one valid Protocol {protocol} packet: {packet.hex(' ')} -> {events}")
    return events[0]


class StreamParser:
    """Incremental packet finder for one protocol.

    ``status=False`` parses instruction packets (the device side); ``status=True`` parses status
    packets (the error byte is split off). :meth:`feed` returns the :class:`Packet` s and
    :class:`ChecksumFailure` s completed by the new bytes. A packet cut off and followed by another
    is detected when the CRC fails and a header appears inside it: the parser drops the cut-off
    part silently and finds the next packet.
    """

    def __init__(self, protocol: int, *, status: bool = False) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol={protocol!r} must be 1 or 2")
        self.protocol = protocol
        self.status = status
        self.buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a packet (or for a header)."""
        return len(self.buf)

    def reset(self) -> None:
        self.buf.clear()

    def feed(self, data: bytes) -> list[Packet | ChecksumFailure]:
        self.buf += data
        out: list[Packet | ChecksumFailure] = []
        step = self._step_p2 if self.protocol == 2 else self._step_p1
        while True:
            ev = step()
            if ev is None:
                return out
            if ev is not True:
                out.append(ev)

    # each step consumes bytes; returns an event, True (progress without event) or None (need more)
    def _step_p2(self):
        buf = self.buf
        i = buf.find(P2_HEADER)
        while i >= 0 and len(buf) > i + 3 and buf[i + 3] == 0xFD:
            i = buf.find(P2_HEADER, i + 1)
        if i < 0:
            # keep a possible header prefix at the end
            keep = 2 if buf.endswith(b"\xff\xff") else 1 if buf.endswith(b"\xff") else 0
            del buf[: len(buf) - keep]
            return None
        if i:
            del buf[:i]
        if len(buf) < 7:
            return None
        length = buf[5] | buf[6] << 8
        min_len = 4 if self.status else 3
        if buf[3] != P2_RESERVED or buf[4] in (0xFD, 0xFF) or length < min_len or length > MAX_PACKET_LEN:
            del buf[0]
            return True
        total = 7 + length
        if len(buf) < total:
            return None
        pkt = bytes(buf[:total])
        if crc16(pkt[:-2]) != (pkt[-2] | pkt[-1] << 8):
            inner = self._inner_header(pkt, P2_HEADER)
            if inner:
                del buf[:inner]  # a cut-off packet followed by a new one: resync silently
                return True
            del buf[:total]
            return ChecksumFailure(2, pkt[4], pkt[7])
        del buf[:total]
        body = unstuff(pkt[7:-2])
        if self.status:
            return Packet(2, pkt[4], body[0], body[2:], error=body[1])
        return Packet(2, pkt[4], body[0], body[1:])

    def _step_p1(self):
        buf = self.buf
        i = buf.find(P1_HEADER)
        while i >= 0 and len(buf) > i + 2 and buf[i + 2] == 0xFF:
            i += 1  # FF FF FF: the header is the last two
            i = buf.find(P1_HEADER, i)
        if i < 0:
            keep = 1 if buf.endswith(b"\xff") else 0
            del buf[: len(buf) - keep]
            return None
        if i:
            del buf[:i]
        if len(buf) < 4:
            return None
        length = buf[3]
        if length < 2:
            del buf[0]
            return True
        total = 4 + length
        if len(buf) < total:
            return None
        pkt = bytes(buf[:total])
        if checksum_p1(pkt[2:-1]) != pkt[-1]:
            inner = self._inner_header(pkt, P1_HEADER)
            if inner:
                del buf[:inner]
                return True
            del buf[:total]
            return ChecksumFailure(1, pkt[2], pkt[4])
        del buf[:total]
        if self.status:
            return Packet(1, pkt[2], STATUS, pkt[5:-1], error=pkt[4])
        return Packet(1, pkt[2], pkt[4], pkt[5:-1])

    @staticmethod
    def _inner_header(pkt: bytes, header: bytes) -> int:
        j = pkt.find(header, 1)
        return j if j > 0 else 0
