"""Dynamixel status packets as pure functions over bytes: find, check and match them to a request.

Nothing here does I/O. :class:`StatusScanner` takes the bytes a port delivered, in any split,
and yields every well-formed status packet (framing, length and CRC-16 on Protocol 2.0 or the
8-bit checksum on Protocol 1.0 checked) and every corrupt candidate; bytes that cannot start a
packet are skipped and counted. :func:`mismatch` then says why a well-formed packet is *not* the
answer to a :class:`Request` (another ID, another instruction, a parameter length the request
does not imply), or ``None`` when it is. The bus (:mod:`tactile_rig.drivers.dynamixel.bus`)
sends through dynamixel-sdk and receives through these functions: a packet becomes a value only
after both checks passed.

Protocol facts (ROBOTIS e-manual, Protocol 2.0 and 1.0 pages; headers, IDs and instruction codes
are :mod:`tactile_rig.devices.dynamixel.packets`, shared with the mock):

* P2: ``FF FF FD 00 | ID | LEN_L LEN_H | 0x55 | ERR | params | CRC_L CRC_H``; LEN = params + 4;
  CRC-16 (polynomial 0x8005, initial value 0, not reflected) over the stuffed packet from the
  header to the last parameter; ``FF FF FD`` inside the payload is stuffed as ``FF FF FD FD``.
* P1: ``FF FF | ID | LEN | ERR | params | CHK``; LEN = params + 2; CHK = ~(ID + LEN + ERR +
  params) & 0xFF; bit 7 of ERR is always 0.

This codec and the mock firmware's (:mod:`tactile_rig.mocks.dynamixel.codec`) are kept separate on
purpose: each is written from the e-manual, so a bug in one cannot hide in the other.
"""

from __future__ import annotations

from dataclasses import dataclass

from tactile_rig.devices.dynamixel.error_codes import P1_COMMAND_MASK
from tactile_rig.devices.dynamixel.packets import (
    ACTION,
    BROADCAST_ID,
    CLEAR,
    CRC16_POLY,
    FACTORY_RESET,
    FAST_BULK_READ,
    FAST_SYNC_READ,
    P1_HEADER,
    P2_HEADER,
    P2_RESERVED,
    PING,
    READ,
    REBOOT,
    REG_WRITE,
    STATUS_INSTRUCTION,
    WRITE,
)

__all__ = [
    "ACTION", "BROADCAST_ID", "CLEAR", "Corrupt", "FACTORY_RESET", "FAST_BULK_READ", "FAST_SYNC_READ", "Foreign",
    "P1_HEADER", "P2_HEADER", "PING", "READ", "REBOOT", "REG_WRITE", "Request", "STATUS_INSTRUCTION",
    "StatusPacket", "StatusScanner", "WRITE", "checksum_p1", "crc16", "encode_instruction_p2", "encode_status",
    "fast_status_params", "mismatch", "parse_status", "split_fast_status", "stuff", "unstuff",
]
#: instructions whose status carries no parameters
_NO_PARAMS = (WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT, CLEAR)

#: longest status payload accepted (a read of the whole MX-64 P2 control table is 147 bytes)
MAX_P2_LENGTH = 1024
MAX_P1_LENGTH = 250  # the SDK's RXPACKET_MAX_LEN
P1_ERROR_RESERVED_BIT = 0x80
#: error bits that reject the command (a status that may come without the read's data)
P2_ERROR_NUMBER_MASK = 0x7F


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC16_POLY) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray) -> int:
    """Protocol 2.0 CRC-16 (poly 0x8005, init 0, MSB first) of ``data``."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def checksum_p1(body: bytes | bytearray) -> int:
    """Protocol 1.0 checksum of ``ID LEN INST/ERR params``: the inverted low byte of their sum."""
    return ~sum(body) & 0xFF


def unstuff(payload: bytes) -> bytes:
    """Remove Protocol 2.0 byte stuffing (``FF FF FD FD`` → ``FF FF FD``)."""
    return payload.replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


@dataclass(frozen=True)
class StatusPacket:
    """A well-formed status packet: framing and CRC/checksum checked, parameters unstuffed."""

    protocol: int
    dxl_id: int
    error: int
    params: bytes
    raw: bytes

    @property
    def rejected(self) -> bool:
        """The servo refused the command (P2 error number, P1 command error bits)."""
        if self.protocol == 2:
            return bool(self.error & P2_ERROR_NUMBER_MASK)
        return bool(self.error & P1_COMMAND_MASK)


@dataclass(frozen=True)
class Corrupt:
    """Bytes that framed like a status packet but failed the CRC/checksum or a header check."""

    raw: bytes
    reason: str


@dataclass(frozen=True)
class Foreign:
    """A well-formed Protocol 2.0 packet that is not a status packet (an echo of an instruction)."""

    raw: bytes
    instruction: int


@dataclass(frozen=True)
class Request:
    """What was asked: ``instruction`` to ``dxl_id`` with ``params`` (the instruction's parameters).

    ``expected_params`` is the number of status parameters the answer must carry, or ``None``
    when the request expects no status (broadcast ID).
    """

    protocol: int
    dxl_id: int
    instruction: int
    params: bytes = b""
    #: the status parameter count when the instruction does not imply it (a Fast Sync/Bulk Read's
    #: one combined status from the broadcast ID)
    expect_params: int | None = None

    @property
    def expected_params(self) -> int | None:
        if self.expect_params is not None:
            return self.expect_params
        if self.dxl_id == BROADCAST_ID:
            return None
        if self.instruction == PING:
            return 3 if self.protocol == 2 else 0
        if self.instruction == READ:
            p = self.params
            if self.protocol == 2:
                if len(p) != 4:
                    raise ValueError(f"a Protocol 2.0 read has 4 parameter bytes, got {len(p)}")
                return p[2] | p[3] << 8
            if len(p) != 2:
                raise ValueError(f"a Protocol 1.0 read has 2 parameter bytes, got {len(p)}")
            return p[1]
        if self.instruction in _NO_PARAMS:
            return 0
        raise ValueError(f"instruction 0x{self.instruction:02x} has no single status packet")

    def signatures(self) -> frozenset[tuple[int, int]]:
        """(ID, parameter count) of every status that could answer this request: its data, or a
        parameterless rejection."""
        n = self.expected_params
        if n is None:
            return frozenset()
        return frozenset({(self.dxl_id, n), (self.dxl_id, 0)})


def mismatch(request: Request, packet: StatusPacket) -> str | None:
    """Why ``packet`` is not the answer to ``request`` (``None``: it is).

    The answer comes from the request's ID, on the request's protocol, with exactly the number of
    parameters the request implies; a rejection (error number / command bits) may come without
    parameters.
    """
    if packet.protocol != request.protocol:
        return f"a Protocol {packet.protocol} packet, expected Protocol {request.protocol}"
    if packet.dxl_id != request.dxl_id:
        return f"status from ID {packet.dxl_id}, expected ID {request.dxl_id}"
    n = request.expected_params
    if n is None:
        return "the request expects no status packet"
    if len(packet.params) == n:
        return None
    if not packet.params and packet.rejected:
        return None
    return f"{len(packet.params)} parameter byte(s), expected {n}"


class StatusScanner:
    """Incremental status-packet finder for one protocol; feed it bytes in any split.

    :meth:`feed` returns the events completed by the new bytes, in order: :class:`StatusPacket`,
    :class:`Corrupt`, :class:`Foreign`. ``skipped`` counts bytes dropped while hunting for a
    header. ``max_params``: the most status parameters the caller can expect; a longer length
    field is taken for corruption at once instead of waiting for that many bytes. After a checksum failure the scan resumes one byte after the false header, so a real
    packet hidden behind garbage that looked like a header is still found.
    """

    def __init__(self, protocol: int, *, max_params: int | None = None) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol={protocol!r} must be 1 or 2")
        self.protocol = protocol
        # A corrupted length field must not swallow the real answer behind it: a frame longer
        # than any status the caller can expect is not waited for (the scan moves on one byte).
        if max_params is None:
            self.max_length = MAX_P2_LENGTH if protocol == 2 else MAX_P1_LENGTH
        else:
            self.max_length = (2 * max_params + 4) if protocol == 2 else max_params + 2  # P2: stuffing
        self.buf = bytearray()
        self.skipped = 0

    @property
    def pending(self) -> bytes:
        """Bytes held for a packet not yet complete (a cut-off packet when the line goes quiet)."""
        return bytes(self.buf)

    def bytes_wanted(self) -> int:
        """How many more bytes would complete the packet being assembled (at least 1)."""
        need = self._total_length()
        if need is None:
            head = 7 if self.protocol == 2 else 4
            return max(1, head - len(self.buf))
        return max(1, need - len(self.buf))

    def _total_length(self) -> int | None:
        b = self.buf
        if self.protocol == 2:
            if len(b) < 7 or b[:3] != P2_HEADER:
                return None
            return 7 + (b[5] | b[6] << 8)
        if len(b) < 4 or b[:2] != P1_HEADER:
            return None
        return 4 + b[3]

    def feed(self, data: bytes) -> list[StatusPacket | Corrupt | Foreign]:
        self.buf += data
        out: list[StatusPacket | Corrupt | Foreign] = []
        while True:
            ev = self._step()
            if ev is None:
                return out
            if not isinstance(ev, bool):
                out.append(ev)

    def _drop(self, n: int) -> None:
        del self.buf[:n]
        self.skipped += n

    def _step(self) -> StatusPacket | Corrupt | Foreign | bool | None:
        """One scanning step: an event, ``True`` (progress, no event) or ``None`` (need bytes)."""
        header = P2_HEADER if self.protocol == 2 else P1_HEADER
        b = self.buf
        i = b.find(header)
        if i < 0:
            # keep a tail that may be the start of a header
            keep = 0
            for k in range(len(header) - 1, 0, -1):
                if b.endswith(header[:k]):
                    keep = k
                    break
            if len(b) > keep:
                self._drop(len(b) - keep)
            return None
        if i:
            self._drop(i)
            return True
        return self._step_p2() if self.protocol == 2 else self._step_p1()

    def _step_p2(self) -> StatusPacket | Corrupt | Foreign | bool | None:
        b = self.buf
        if len(b) < 8:
            return None
        if b[3] == 0xFD:  # FF FF FD FD: stuffed payload bytes, not a header
            self._drop(1)
            return True
        length = b[5] | b[6] << 8
        if b[3] != P2_RESERVED or b[4] > 0xFE or not 3 <= length <= self.max_length:
            self._drop(1)
            return True
        total = 7 + length
        if len(b) < total:
            return None
        raw = bytes(b[:total])
        if crc16(raw[:-2]) != (raw[-2] | raw[-1] << 8):
            self._drop(1)
            return Corrupt(raw, "CRC mismatch")
        del b[:total]
        if raw[7] != STATUS_INSTRUCTION:
            return Foreign(raw, raw[7])
        if length < 4:
            return Corrupt(raw, "status packet without an error byte")
        return StatusPacket(2, raw[4], raw[8], unstuff(raw[9:-2]), raw)

    def _step_p1(self) -> StatusPacket | Corrupt | bool | None:
        b = self.buf
        if len(b) < 4:
            return None
        if b[2] >= BROADCAST_ID or not 2 <= b[3] <= self.max_length:  # FF FF FF ..: the header is one byte on
            self._drop(1)
            return True
        total = 4 + b[3]
        if len(b) < total:
            return None
        raw = bytes(b[:total])
        if checksum_p1(raw[2:-1]) != raw[-1]:
            self._drop(1)
            return Corrupt(raw, "checksum mismatch")
        if raw[4] & P1_ERROR_RESERVED_BIT:
            self._drop(1)
            return Corrupt(raw, "error byte with the reserved bit 7 set")
        del b[:total]
        return StatusPacket(1, raw[2], raw[4], raw[5:-1], raw)


def fast_status_params(sizes: list[int]) -> int:
    """Parameter count of the combined status of a Fast Sync/Bulk Read of these data sizes:
    ``[ERR ID DATA CRC]`` per servo, the first ERR in the error byte, the last CRC the packet's."""
    return sum(n + 4 for n in sizes) - 3


def split_fast_status(packet: StatusPacket, expected: list[tuple[int, int]]) -> dict[int, tuple[int, bytes]]:
    """A Fast Sync/Bulk Read's combined status → {ID: (error, data)}, in the order asked.

    Checks each servo's ID and the cumulative CRC each one appended (the packet's own CRC was
    checked by the scanner); ``ValueError`` names the first problem."""
    if packet.dxl_id != BROADCAST_ID:
        raise ValueError(f"a fast read status comes from ID 0xFE, not {packet.dxl_id}")
    if len(packet.params) != fast_status_params([n for _, n in expected]):
        raise ValueError(f"{len(packet.params)} parameter byte(s), expected "
                         f"{fast_status_params([n for _, n in expected])}")
    raw = packet.raw
    body = raw[8:-2]  # ERR1 ID1 DATA1 CRC1 ... ERRk IDk DATAk
    out: dict[int, tuple[int, bytes]] = {}
    pos = 0
    for k, (dxl_id, n) in enumerate(expected):
        err, sid = body[pos], body[pos + 1]
        if sid != dxl_id:
            raise ValueError(f"segment {k} is from ID {sid}, expected ID {dxl_id}")
        data = body[pos + 2:pos + 2 + n]
        end = 8 + pos + 2 + n
        if k < len(expected) - 1 and crc16(raw[:end]) != (raw[end] | raw[end + 1] << 8):
            raise ValueError(f"segment {k} (ID {dxl_id}) fails its CRC")
        out[dxl_id] = (err, bytes(data))
        pos += n + 4
    return out


def parse_status(protocol: int, data: bytes) -> list[StatusPacket | Corrupt | Foreign]:
    """Every event in ``data`` (a complete byte string), as :class:`StatusScanner` finds them."""
    return StatusScanner(protocol).feed(data)


def stuff(payload: bytes) -> bytes:
    """Protocol 2.0 byte stuffing of instruction + parameters (``FF FF FD`` → ``FF FF FD FD``)."""
    out = bytearray()
    for b in payload:
        out.append(b)
        if b == 0xFD and out[-3:-1] == b"\xff\xff" and len(out) >= 3:
            out.append(0xFD)
    return bytes(out)


def encode_instruction_p2(dxl_id: int, instruction: int, params: bytes) -> bytes:
    """A Protocol 2.0 instruction packet, stuffed (for payloads the SDK 4.1.0 does not stuff)."""
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    pkt = P2_HEADER + bytes([P2_RESERVED, dxl_id, length & 0xFF, length >> 8]) + body
    crc = crc16(pkt)
    return pkt + bytes([crc & 0xFF, crc >> 8])


def encode_status(protocol: int, dxl_id: int, error: int, params: bytes) -> bytes:
    """A status packet (for tests and tools: the host never sends one)."""
    if protocol == 2:
        body = bytes(params).replace(b"\xff\xff\xfd", b"\xff\xff\xfd\xfd")
        length = len(body) + 4
        pkt = P2_HEADER + bytes([P2_RESERVED, dxl_id, length & 0xFF, length >> 8, STATUS_INSTRUCTION, error]) + body
        crc = crc16(pkt)
        return pkt + bytes([crc & 0xFF, crc >> 8])
    body = bytes([dxl_id, len(params) + 2, error]) + bytes(params)
    return P1_HEADER + body + bytes([checksum_p1(body)])
