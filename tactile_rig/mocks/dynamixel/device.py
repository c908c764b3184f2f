"""A mock Dynamixel bus: several MX-64 firmwares behind one serial line.

Parses the host's instruction packets with the mock's own codec, dispatches them to the servos
(unicast or broadcast), and sends their status packets with the wire time at the bus baud plus each
servo's Return Delay Time, one after another as servos on a half-duplex bus do.
"""

from __future__ import annotations

from typing import Any

from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.devices.dynamixel.packets import (
    ACTION,
    BROADCAST_ID,
    BULK_READ,
    BULK_WRITE,
    CLEAR,
    CLEAR_MULTI_TURN,
    FACTORY_RESET,
    FAST_BULK_READ,
    FAST_SYNC_READ,
    P2_HEADER,
    P2_RESERVED,
    PING,
    READ,
    REBOOT,
    REG_WRITE,
    RESET_ALL,
    RESET_ALL_BUT_ID,
    RESET_ALL_BUT_ID_AND_BAUD,
    STATUS_INSTRUCTION,
    SYNC_READ,
    SYNC_WRITE,
    WRITE,
)
from tactile_rig.mocks.dynamixel.codec import (
    ChecksumFailure,
    Packet,
    StreamParser,
    crc16,
    encode_p1,
    encode_p2_status,
)
from tactile_rig.mocks.dynamixel.firmware import Servo
from tactile_rig.mocks.serial_device import SerialDevice

#: a partial packet older than this is dropped when new bytes arrive (the firmware's RX timeout)
RX_IDLE_TIMEOUT_S = 0.02
#: bauds the SDK and common adapters use; a servo's nominal rate is the closest within 3 %
STANDARD_BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
                  1_000_000, 1_152_000, 2_000_000, 2_250_000, 2_500_000, 3_000_000, 3_500_000,
                  4_000_000, 4_500_000)



def nominal_baud(bps: int) -> int:
    """The standard rate a UART at ``bps`` talks to without errors (within 3 %), else ``bps``."""
    best = min(STANDARD_BAUDS, key=lambda b: abs(b - bps))
    return best if abs(best - bps) <= 0.03 * best else bps


class DynamixelBusDevice(SerialDevice):
    """Servos sharing one line; ``servos`` all speak ``protocol``."""

    kind = "dynamixel"

    def __init__(self, servos: list[Servo], *, protocol: int, baud: int, timing: bool = True,
                 boot_s: float = 0.05) -> None:
        super().__init__(baud=baud, timing=timing)
        if not servos:
            raise ValueError("a Dynamixel bus needs at least one servo")
        ids = [s.id for s in servos]
        if len(set(ids)) != len(ids):
            raise ValueError(f"servo IDs must be unique on one bus, got {ids}")
        self.protocol = protocol
        self.servos = servos
        self.boot_s = boot_s
        self.parser = StreamParser(protocol)
        self._last_rx_s = 0.0
        self.packets_seen = 0
        self.checksum_failures = 0

    def describe(self) -> dict[str, Any]:
        return {"protocol": self.protocol, "ids": [s.id for s in self.servos],
                "model": self.servos[0].table.model_number}

    def servo(self, dxl_id: int) -> Servo | None:
        for s in self.servos:
            if s.id == dxl_id:
                return s
        return None

    # -- SerialDevice hooks ----------------------------------------------------------------------
    def on_open(self, t_s: float) -> None:
        self.parser.reset()

    def on_tick(self, t_s: float) -> None:
        for s in self.servos:
            s.advance_to(t_s)

    def on_bytes(self, data: bytes, t_s: float) -> None:
        if self.parser.pending and t_s - self._last_rx_s > RX_IDLE_TIMEOUT_S:
            self.parser.reset()
        self._last_rx_s = t_s
        for ev in self.parser.feed(data):
            if isinstance(ev, ChecksumFailure):
                self.checksum_failures += 1
                s = self._target(ev.id, t_s)
                if s is not None:
                    self._status(s, de.CRC_ERROR if self.protocol == 2 else de.P1_CHECKSUM, b"", t_s)
                continue
            self.packets_seen += 1
            if self.protocol == 2:
                self._handle_p2(ev, t_s)
            else:
                self._handle_p1(ev, t_s)

    # -- replies -----------------------------------------------------------------------------------
    def _target(self, dxl_id: int, t_s: float) -> Servo | None:
        s = self.servo(dxl_id)
        return s if s is not None and s.booted_at_s <= t_s else None

    def _awake(self, t_s: float) -> list[Servo]:
        return sorted((s for s in self.servos if s.booted_at_s <= t_s), key=lambda s: s.id)

    def _encode(self, dxl_id: int, s: Servo, error: int, params: bytes) -> bytes:
        if self.protocol == 2:
            return encode_p2_status(dxl_id, s.status_error(error), params)
        return encode_p1(dxl_id, s.status_error(error), params)

    def _status(self, s: Servo, error: int, params: bytes, t_s: float, *, level: int = 2,
                dxl_id: int | None = None) -> float:
        """Send ``s``'s status packet after its return delay, if its Status Return Level allows.

        ``dxl_id``: the ID the instruction was addressed to (the answer to a write of the ID
        register still comes from the old ID)."""
        if s.status_return_level < level:
            return t_s
        return self.emit(self._encode(s.id if dxl_id is None else dxl_id, s, error, params), t_s,
                         delay_s=s.return_delay_s)

    # -- Protocol 2.0 ------------------------------------------------------------------------------
    def _handle_p2(self, pkt: Packet, t: float) -> None:
        inst, p = pkt.instruction, pkt.params
        bcast = pkt.id == BROADCAST_ID
        if inst in (SYNC_READ, FAST_SYNC_READ, SYNC_WRITE, BULK_READ, FAST_BULK_READ, BULK_WRITE):
            if bcast:
                self._group_p2(inst, p, t)
            return
        targets = self._awake(t) if bcast else [s for s in [self._target(pkt.id, t)] if s is not None]
        for s in targets:
            if inst == PING:
                model = s.item("Model Number")
                t = self._status(s, 0, bytes([model & 0xFF, model >> 8, s.item("Firmware Version")]), t, level=0)
            elif bcast and inst not in (WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT, CLEAR):
                continue  # a broadcast read has no single answer: ignored
            else:
                self._unicast_p2(s, inst, p, t, bcast)

    def _unicast_p2(self, s: Servo, inst: int, p: bytes, t: float, bcast: bool) -> None:
        old_id = s.id
        reply = (lambda err, params=b"", level=2: t if bcast else self._status(s, err, params, t, level=level,
                                                                               dxl_id=old_id))
        if inst == READ:
            if len(p) != 4:
                reply(de.DATA_LENGTH, level=1)
                return
            err, data = s.read(p[0] | p[1] << 8, p[2] | p[3] << 8)
            reply(err, data, level=1)
        elif inst in (WRITE, REG_WRITE):
            if len(p) < 3:
                reply(de.DATA_LENGTH)
                return
            addr, data = p[0] | p[1] << 8, p[2:]
            old_baud = s.baud
            if inst == WRITE:
                err = s.write(addr, data)
            else:
                err = s.check_write(addr, data)
                if not err:
                    s.registered = (addr, bytes(data))
                    s._write_raw_item("Registered Instruction", 1)
            reply(err)
            if s.baud != old_baud:
                self.baud = nominal_baud(s.baud)  # the line follows the servo after its status
        elif inst == ACTION:
            if s.registered is None:
                reply(de.INSTRUCTION_ERROR)
                return
            addr, data = s.registered
            s.registered = None
            s._write_raw_item("Registered Instruction", 0)
            reply(s.write(addr, data))
        elif inst == FACTORY_RESET:
            if len(p) != 1 or p[0] not in (RESET_ALL_BUT_ID, RESET_ALL_BUT_ID_AND_BAUD, RESET_ALL):
                reply(de.DATA_RANGE if len(p) == 1 else de.DATA_LENGTH)
                return
            if bcast and p[0] == RESET_ALL:
                return  # ignored by firmware >= 42: it would give every servo ID 1
            end = reply(0)
            s.factory_reset(p[0], end, self.boot_s)
            self.baud = nominal_baud(s.baud)
        elif inst == REBOOT:
            end = reply(0)
            s.reboot(end, self.boot_s)
        elif inst == CLEAR:
            ok = p == CLEAR_MULTI_TURN
            reply(0 if ok else de.DATA_RANGE)
        else:
            reply(de.INSTRUCTION_ERROR)

    def _group_p2(self, inst: int, p: bytes, t: float) -> None:
        if inst in (SYNC_READ, FAST_SYNC_READ, SYNC_WRITE):
            if len(p) < 4:
                return
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            rest = p[4:]
            if inst == SYNC_WRITE:
                for k in range(0, len(rest) - n, n + 1):
                    s = self._target(rest[k], t)
                    if s is not None:
                        s.write(addr, rest[k + 1:k + 1 + n])
                return
            reqs = [(i, addr, n) for i in rest]
        elif inst == BULK_WRITE:
            k = 0
            while k + 5 <= len(p):
                n = p[k + 3] | p[k + 4] << 8
                s = self._target(p[k], t)
                if s is not None:
                    s.write(p[k + 1] | p[k + 2] << 8, p[k + 5:k + 5 + n])
                k += 5 + n
            return
        else:
            reqs = [(p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8) for k in range(0, len(p) - 4, 5)]
        answers = []
        for dxl_id, addr, n in reqs:
            s = self._target(dxl_id, t)
            if s is not None and s.status_return_level >= 1:
                err, data = s.read(addr, n)
                answers.append((s, err, data))
        if inst in (FAST_SYNC_READ, FAST_BULK_READ):
            self._fast_reply(answers, t)
            return
        for s, err, data in answers:
            t = self._status(s, err, data, t, level=1)

    def _fast_reply(self, answers: list[tuple[Servo, int, bytes]], t: float) -> None:
        """One status packet from ID 0xFE: [ERR ID DATA CRC] per servo, the last CRC the packet's."""
        if not answers:
            return
        length = 1 + sum(len(d) + 4 for _, _, d in answers)
        pkt = bytearray(P2_HEADER + bytes([P2_RESERVED, BROADCAST_ID, length & 0xFF, length >> 8, STATUS_INSTRUCTION]))
        for s, err, data in answers:
            pkt += bytes([s.status_error(err), s.id]) + data
            crc = crc16(pkt)
            pkt += bytes([crc & 0xFF, crc >> 8])
        self.emit(bytes(pkt), t, delay_s=answers[0][0].return_delay_s)

    # -- Protocol 1.0 ------------------------------------------------------------------------------
    def _handle_p1(self, pkt: Packet, t: float) -> None:
        inst, p = pkt.instruction, pkt.params
        bcast = pkt.id == BROADCAST_ID
        if inst == SYNC_WRITE:
            if bcast and len(p) >= 2:
                addr, n = p[0], p[1]
                for k in range(2, len(p) - n, n + 1):
                    s = self._target(p[k], t)
                    if s is not None:
                        s.write(addr, p[k + 1:k + 1 + n])
            return
        if inst == BULK_READ:
            if bcast and p[:1] == b"\x00":
                for k in range(1, len(p) - 2, 3):
                    s = self._target(p[k + 1], t)
                    if s is not None:
                        err, data = s.read(p[k + 2], p[k])
                        t = self._status(s, err, data, t, level=1)
            return
        targets = self._awake(t) if bcast else [s for s in [self._target(pkt.id, t)] if s is not None]
        for s in targets:
            reply = (lambda err, params=b"", level=2, s=s, old_id=s.id:
                     t if bcast else self._status(s, err, params, t, level=level, dxl_id=old_id))
            if inst == PING:
                if not bcast:
                    self._status(s, 0, b"", t, level=0)
            elif inst == READ:
                if len(p) != 2:
                    reply(de.P1_INSTRUCTION, level=1)
                    continue
                err, data = s.read(p[0], p[1])
                reply(err, data, level=1)
            elif inst in (WRITE, REG_WRITE):
                if len(p) < 2:
                    reply(de.P1_INSTRUCTION)
                    continue
                old_baud = s.baud
                if inst == WRITE:
                    err = s.write(p[0], p[1:])
                else:
                    err = s.check_write(p[0], p[1:])
                    if not err:
                        s.registered = (p[0], bytes(p[1:]))
                        s._write_raw_item("Registered", 1)
                reply(err)
                if s.baud != old_baud:
                    self.baud = nominal_baud(s.baud)
            elif inst == ACTION:
                if s.registered is not None:
                    addr, data = s.registered
                    s.registered = None
                    s._write_raw_item("Registered", 0)
                    reply(s.write(addr, data))
                else:
                    reply(de.P1_INSTRUCTION)
            elif inst == FACTORY_RESET:
                end = reply(0)
                s.factory_reset(RESET_ALL, end, self.boot_s)
                self.baud = nominal_baud(s.baud)
            elif inst == REBOOT:  # MX firmware >= 41 also accepts Reboot on Protocol 1.0
                end = reply(0)
                s.reboot(end, self.boot_s)
            else:
                reply(de.P1_INSTRUCTION)
