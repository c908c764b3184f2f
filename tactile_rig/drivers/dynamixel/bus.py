"""The Dynamixel bus: dynamixel-sdk sends, :mod:`.wire` checks every status packet, typed errors.

:class:`DynamixelBus` speaks the instructions (ping, read and write items or raw bytes, reboot,
factory reset, Sync/Bulk Read and their Fast variants, Sync Write) through one validated exchange
at a time (:class:`~tactile_rig.drivers.dynamixel.link.BusLink`: the bus lock, stale input
flushed, late statuses resynchronised, the port's loss and return).

Reads and pings are retried (``retries``, default 2) on ``DeviceTimeout`` / ``LinkCorrupt``; a
write whose status was lost is never blindly repeated: the bus reads the register back, and
writes again only if the value is not there. Errors:

* no status before the packet timeout → :class:`~tactile_rig.core.errors.DeviceTimeout`
* corrupt or cut-off status → :class:`~tactile_rig.core.errors.LinkCorrupt`
* the port vanished (EIO, unplugged) → :class:`~tactile_rig.core.errors.NotConnected`; later calls
  fail fast with ``NotConnected`` until :class:`~tactile_rig.drivers.reconnect.Reconnect` says to
  try again, and the bus reopens the port when it is back
* the port is held by another process → :class:`~tactile_rig.core.errors.PortInUse`
* a status error number (P2) or command bit (P1) → :class:`CommandRejected` naming it
* the Alert bit (P2) or a hardware bit (P1) → :class:`~tactile_rig.core.errors.DeviceFault` with the
  decoded Hardware Error Status, for writes; reads still return their data while a fault is latched.
"""

from __future__ import annotations

import logging
from typing import Iterable

import tactile_rig.drivers.dynamixel.wire as wire
from tactile_rig.core.deprecation import renamed_kwargs
from tactile_rig.core.errors import (
    CommandRejected,
    DeviceFault,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
)
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.devices.dynamixel import packets as pk
from tactile_rig.drivers.dynamixel.link import LATE_HORIZON_S, BusLink, BusStats
from tactile_rig.drivers.dynamixel.port import DEFAULT_LATENCY_TIMER_MS, UrlPortHandler, check_latency_timer
from tactile_rig.drivers.reconnect import Reconnect

__all__ = [
    "BusStats", "CommandRejected", "DEFAULT_LATENCY_TIMER_MS", "DynamixelBus", "LATE_HORIZON_S", "UrlPortHandler",
    "check_latency_timer",
]

log = logging.getLogger("tactile_rig.dynamixel")


class DynamixelBus(BusLink):
    """One Dynamixel bus: a port at a baud rate speaking one protocol.

    ``port`` is a device path or URL. Every method takes the bus lock, so drivers for several
    servos on one port may run in several threads.

    ``latency_timer_ms`` is the USB adapter's latency timer (FTDI default 16 ms; 1 ms after
    ``echo 1 > /sys/bus/usb-serial/devices/ttyUSBn/latency_timer``): the packet timeout allows
    twice it, and the value read from sysfs is used when it is larger. ``retries`` bounds the
    retries of idempotent reads. ``reconnect_policy`` is the backoff policy after an unplug.
    """

    @renamed_kwargs(reconnect="reconnect_policy")
    def __init__(self, port: str, *, baudrate: int = 1_000_000, protocol: int = 2,
                 latency_timer_ms: float = DEFAULT_LATENCY_TIMER_MS, retries: int = 2,
                 reconnect_policy: Reconnect | None = None, exclusive: bool | None = None) -> None:
        super().__init__(port, baudrate=baudrate, protocol=protocol, latency_timer_ms=latency_timer_ms,
                         retries=retries, reconnect_policy=reconnect_policy, exclusive=exclusive)
        #: last hardware error bits seen per ID (P2 Hardware Error Status layout)
        self.hardware_errors: dict[int, int] = {}

    # -- result handling -------------------------------------------------------------------------
    def _check_status(self, dxl_id: int, error: int, what: str, *, fault_ok: bool) -> None:
        dev = self.name(dxl_id)
        if self.protocol == 2:
            number, alert = error & 0x7F, bool(error & de.ALERT_BIT)
            if number:
                name = de.P2_ERROR_NUMBERS.get(number, f"error {number}")
                raise CommandRejected(f"{what}: the servo answered error {number} ({name})", device=dev,
                                      code=number, detail=name)
            if not alert:
                self.hardware_errors[dxl_id] = 0
                return
            hw = self.hardware_errors.get(dxl_id) or 0
            if not hw:
                # The Alert bit says "read Hardware Error Status"; reads are allowed while faulted.
                addr = self.table["Hardware Error Status"].address
                req = wire.Request(2, dxl_id, wire.READ, self._read_params(addr, 1))
                try:
                    pkt = self._retrying(lambda: self._txrx(req, "read Hardware Error Status"))
                    hw = pkt.params[0] if len(pkt.params) == 1 else 0
                except (DeviceTimeout, LinkCorrupt):
                    hw = 0
            self.hardware_errors[dxl_id] = hw
        else:
            cmd = error & de.P1_COMMAND_MASK
            if cmd:
                names = ", ".join(de.decode_bits(cmd, de.P1_ERROR_BITS))
                raise CommandRejected(f"{what}: the servo answered error bits 0x{cmd:02x} ({names})", device=dev,
                                      code=cmd, detail=names)
            hw = de.p1_hardware_to_status_bits(error & de.P1_HARDWARE_MASK)
            self.hardware_errors[dxl_id] = hw
            if not hw:
                return
        if not fault_ok:
            raise self.fault_error(dxl_id, what)

    def fault_error(self, dxl_id: int, what: str = "hardware error") -> DeviceFault:
        """The DeviceFault describing ``dxl_id``'s latched hardware error."""
        hw = self.hardware_errors.get(dxl_id, 0)
        names = de.decode_hardware_error(hw) or ["unknown hardware error"]
        return DeviceFault(f"{what}: hardware error latched: {', '.join(names)} (status 0x{hw:02x}); torque is "
                           "off until reboot()", device=self.name(dxl_id), code=hw, detail=names)

    # -- transactions ----------------------------------------------------------------------------------
    def _read_raw(self, dxl_id: int, address: int, length: int, what: str) -> bytes:
        """Read with retries (bus lock held); the status is checked (faults allowed)."""
        req = wire.Request(self.protocol, dxl_id, wire.READ, self._read_params(address, length))
        pkt = self._retrying(lambda: self._txrx(req, what))
        self._check_status(dxl_id, pkt.error, what, fault_ok=True)
        return pkt.params

    def ping(self, dxl_id: int) -> int:
        """The model number of ``dxl_id``."""
        self._check_id(dxl_id)
        with self.lock:
            pkt = self._retrying(lambda: self._txrx(wire.Request(self.protocol, dxl_id, wire.PING), "ping"))
            self._check_status(dxl_id, pkt.error, "ping", fault_ok=True)
            if self.protocol == 2:
                return pkt.params[0] | pkt.params[1] << 8
            # Protocol 1.0 has no model in the ping status: read it, as the SDK does, twice (the
            # model decides whether a driver accepts the servo; P1's checksum is weak)
            raw = self.read_bytes(dxl_id, 0, 2, what="ping (read Model Number)", verify=True)
            return raw[0] | raw[1] << 8

    def read_bytes(self, dxl_id: int, address: int, length: int, *, what: str | None = None,
                   verify: bool = False) -> bytes:
        """``length`` raw bytes from ``address`` (allowed while a fault is latched).

        ``verify``: read twice, and return only when both reads agree (``LinkCorrupt`` when no two
        consecutive reads agree within ``retries``). Use it for values that must be right on
        Protocol 1.0, whose 8-bit checksum lets some corruptions through (see docs/dynamixel.md);
        not for values that change between two reads (present position while moving).
        """
        self._check_id(dxl_id)
        what = what or f"read {length} byte(s) at {address}"
        with self.lock:
            first = self._read_raw(dxl_id, address, length, what)
            if not verify:
                return bytes(first)
            for _ in range(self.retries + 1):
                second = self._read_raw(dxl_id, address, length, f"{what} (verify)")
                if second == first:
                    return bytes(second)
                self.stats.verify_mismatches += 1
                log.info("%s: %s: two reads disagree (%s vs %s)", self.name(dxl_id), what, first.hex(" "),
                         second.hex(" "))
                first = second
            raise LinkCorrupt(f"{what}: {self.retries + 2} reads never agreed twice in a row (last "
                              f"{first.hex(' ')}); a noisy link or a value that keeps changing", device=self.name(dxl_id))

    def _readback_ok(self, address: int, length: int) -> bool:
        """Whether a write there can be verified by reading it back (not ID / Baud Rate, which
        change how the servo answers)."""
        for name in ("ID", "Baud Rate"):
            it = self.table[name]
            if address < it.address + it.size and it.address < address + length:
                return False
        return True

    def write_bytes(self, dxl_id: int, address: int, data: bytes, *, what: str | None = None,
                    fault_ok: bool = False) -> None:
        """Write raw bytes; a latched fault raises DeviceFault unless ``fault_ok``.

        A write is never blindly repeated: when its status is lost, the register is read back;
        the write counts as done if the value is there and is sent again (at most ``retries``
        times) only if it is not.
        """
        self._check_id(dxl_id)
        what = what or f"write {len(data)} byte(s) at {address}"
        params = (bytes([address & 0xFF, address >> 8]) if self.protocol == 2 else bytes([address])) + bytes(data)
        req = wire.Request(self.protocol, dxl_id, wire.WRITE, params)
        with self.lock:
            for attempt in range(self.retries + 1):
                try:
                    pkt = self._txrx(req, what)
                    break
                except (DeviceTimeout, LinkCorrupt) as exc:
                    if not self._readback_ok(address, len(data)):
                        raise
                    try:
                        back = self._read_raw(dxl_id, address, len(data), f"read back after {what}")
                    except (DeviceTimeout, LinkCorrupt):
                        raise exc from None
                    if back == bytes(data):
                        self.stats.writes_confirmed_by_readback += 1
                        if self.hardware_errors.get(dxl_id) and not fault_ok:
                            raise self.fault_error(dxl_id, what) from None
                        return
                    if attempt == self.retries:
                        raise
                    self.stats.writes_repeated_after_readback += 1
            self._check_status(dxl_id, pkt.error, what, fault_ok=fault_ok)

    def read(self, dxl_id: int, name: str, *, verify: bool = False) -> int:
        """The value of control-table item ``name`` (signed items decoded); ``verify``: see
        :meth:`read_bytes`.

        A writable item's value must lie in its range (the firmware refuses writes outside it, so
        a value beyond it is a damaged status that passed the checksum): it is read again, up to
        ``retries`` times, then ``LinkCorrupt``.
        """
        it = self.table[name]
        checked = it.writable and (it.high - it.low + 1) < (1 << (8 * it.size))
        for _ in range(self.retries + 1):
            raw = int.from_bytes(self.read_bytes(dxl_id, it.address, it.size, what=f"read {name}", verify=verify),
                                 "little")
            value = it.from_raw(raw)
            if not checked or it.low <= value <= it.high:
                return value
            self.stats.implausible_values += 1
            log.info("%s: read %s: %d is outside [%d, %d]: a damaged status, read again", self.name(dxl_id), name,
                     value, it.low, it.high)
        raise LinkCorrupt(f"read {name}: {value} is outside [{it.low}, {it.high}], which the servo never stores "
                          f"({self.retries + 1} reads): a damaged link", device=self.name(dxl_id))

    def write(self, dxl_id: int, name: str, value: int, *, fault_ok: bool = False) -> None:
        """Write item ``name``; values outside its range raise LimitError before anything is sent."""
        it = self.table[name]
        if not it.writable:
            raise LimitError(f"{name} (address {it.address}) is read-only", device=self.name(dxl_id))
        value = int(value)
        if not it.low <= value <= it.high:
            raise LimitError(f"{name}={value} is outside [{it.low}, {it.high}] ({it.unit or 'raw'})",
                             device=self.name(dxl_id))
        self.write_bytes(dxl_id, it.address, it.to_raw(value).to_bytes(it.size, "little"),
                         what=f"write {name}={value}", fault_ok=fault_ok)

    def reboot(self, dxl_id: int) -> None:
        """Send Reboot (clears a latched hardware error; RAM back to defaults, torque off).

        Never repeated: a lost status raises DeviceTimeout / LinkCorrupt (the servo may or may
        not have rebooted; ping it after its boot time)."""
        self._check_id(dxl_id)
        with self.lock:
            # Protocol 1.0: the SDK has no reboot(); MX firmware accepts instruction 0x08.
            pkt = self._txrx(wire.Request(self.protocol, dxl_id, wire.REBOOT), "reboot")
            self.hardware_errors[dxl_id] = 0
            self._check_status(dxl_id, pkt.error & ~de.ALERT_BIT if self.protocol == 2 else
                               pkt.error & de.P1_COMMAND_MASK, "reboot", fault_ok=True)

    def factory_reset(self, dxl_id: int, option: int = 0x02) -> None:
        """Factory Reset (P2 option 0xFF all, 0x01 all but ID, 0x02 all but ID and baud); never repeated."""
        self._check_id(dxl_id)
        params = bytes([option]) if self.protocol == 2 else b""
        with self.lock:
            pkt = self._txrx(wire.Request(self.protocol, dxl_id, wire.FACTORY_RESET, params), "factory reset")
            self._check_status(dxl_id, pkt.error, "factory reset", fault_ok=True)

    def _check_id(self, dxl_id: int) -> None:
        top = 252 if self.protocol == 2 else 253
        if not 0 <= int(dxl_id) <= top:
            raise ValueError(f"dxl_id={dxl_id!r} must be in [0, {top}] (Protocol {self.protocol}) for a unicast")

    # -- group transactions ------------------------------------------------------------------------------
    def _group_receive(self, port: UrlPortHandler, reqs: list[tuple[int, int, int]], tx_bytes: int,
                       what: str) -> dict[int, bytes]:
        """One status per (id, address, size), in order, each validated like a read's."""
        out: dict[int, bytes] = {}
        for k, (i, address, size) in enumerate(reqs):
            req = wire.Request(self.protocol, i, wire.READ, self._read_params(address, size))
            try:
                pkt = self._receive(port, req, tx_bytes if k == 0 else 0, f"{what}: ID {i}")
            except (DeviceTimeout, LinkCorrupt):
                for j, _, n in reqs[k + 1:]:  # their statuses may still come, late
                    self._expect_late(j, n)
                raise
            self._check_status(i, pkt.error, f"{what}: ID {i}", fault_ok=True)
            if len(pkt.params) != size:
                raise LinkCorrupt(f"{what}: no data for ID {i}", device=self.name(i))
            out[i] = pkt.params
        return out

    def _group_read(self, instruction: int, params: bytes, reqs: list[tuple[int, int, int]], what: str
                    ) -> dict[int, bytes]:
        def run() -> dict[int, bytes]:
            port = self._live_port()
            self._begin(port, [i for i, _, _ in reqs], what)
            sent = self._send(port, wire.Request(self.protocol, wire.BROADCAST_ID, instruction, params), what)
            return self._group_receive(port, reqs, sent, what)

        with self.lock:
            return self._retrying(lambda: self._guarded(what, run))

    def sync_read(self, ids: Iterable[int], name: str, *, fast: bool = False) -> dict[int, int]:
        """Item ``name`` of several IDs in one Sync Read (Protocol 2.0; ``fast``: Fast Sync Read)."""
        if self.protocol != 2:
            raise LimitError("Sync Read needs Protocol 2.0 (use bulk_read on Protocol 1.0)", device=self.port_name)
        it = self.table[name]
        ids = list(ids)
        if len(set(ids)) != len(ids):
            raise ValueError(f"sync read: IDs {ids} list one twice")
        params = bytes([it.address & 0xFF, it.address >> 8, it.size & 0xFF, it.size >> 8]) + bytes(ids)
        reqs = [(i, it.address, it.size) for i in ids]
        if fast:
            raw = self._fast_read(wire.FAST_SYNC_READ, params, reqs, f"fast sync read {name}")
        else:
            raw = self._group_read(pk.SYNC_READ, params, reqs, f"sync read {name}")
        return {i: it.from_raw(int.from_bytes(raw[i], "little")) for i in ids}

    def bulk_read(self, requests: Iterable[tuple[int, str]], *, fast: bool = False) -> dict[int, int]:
        """One item per ID in one Bulk Read: ``[(id, item name), ...]`` → {id: value}."""
        reqs = [(i, self.table[n]) for i, n in requests]
        ids = [i for i, _ in reqs]
        if len(set(ids)) != len(ids):
            raise ValueError("bulk read: an ID is listed twice")
        if self.protocol == 2:
            params = b"".join(bytes([i, it.address & 0xFF, it.address >> 8, it.size & 0xFF, it.size >> 8])
                              for i, it in reqs)
        else:
            params = b"\x00" + b"".join(bytes([it.size, i, it.address]) for i, it in reqs)
        group = [(i, it.address, it.size) for i, it in reqs]
        if fast and self.protocol == 2:
            raw = self._fast_read(wire.FAST_BULK_READ, params, group, "fast bulk read")
        else:
            raw = self._group_read(pk.BULK_READ, params, group, "bulk read")
        return {i: it.from_raw(int.from_bytes(raw[i], "little")) for i, it in reqs}

    def _fast_read(self, instruction: int, params: bytes, reqs: list[tuple[int, int, int]], what: str
                   ) -> dict[int, bytes]:
        """A Fast Sync/Bulk Read: one combined status from the broadcast ID, each servo's segment
        checked (ID, order, its CRC) and its error handled as a read's."""
        sizes = [n for _, _, n in reqs]
        n_fast = wire.fast_status_params(sizes)
        req = wire.Request(2, wire.BROADCAST_ID, instruction, params, expect_params=n_fast)

        def run() -> dict[int, bytes]:
            port = self._live_port()
            self._begin(port, [i for i, _, _ in reqs], what)
            sent = self._send(port, req, what)
            try:
                pkt = self._receive(port, req, sent, what, exact=True)
                segments = wire.split_fast_status(pkt, [(i, n) for i, _, n in reqs])
            except ValueError as exc:
                for i, _, _ in reqs:
                    self._expect_late(i, n_fast)
                raise LinkCorrupt(f"{what}: {exc}", device=self.port_name) from None
            except (DeviceTimeout, LinkCorrupt):
                for i, _, _ in reqs:  # their segments may still come: resync each servo first (and
                    self._expect_late(i, n_fast)  # let the scanner frame the late status whole)
                raise
            for i, (err, _) in segments.items():
                self._check_status(i, err, f"{what}: ID {i}", fault_ok=True)
            return {i: data for i, (_, data) in segments.items()}

        with self.lock:
            return self._retrying(lambda: self._guarded(what, run))

    def sync_write(self, name: str, values: dict[int, int]) -> None:
        """Write item ``name`` of several IDs in one Sync Write (no status packets)."""
        it = self.table[name]
        body = bytearray()
        for i, v in values.items():
            if not it.low <= int(v) <= it.high:
                raise LimitError(f"{name}={v} is outside [{it.low}, {it.high}]", device=self.name(i))
            body += bytes([i]) + it.to_raw(int(v)).to_bytes(it.size, "little")
        if self.protocol == 2:
            params = bytes([it.address & 0xFF, it.address >> 8, it.size & 0xFF, it.size >> 8]) + bytes(body)
        else:
            params = bytes([it.address, it.size]) + bytes(body)
        what = f"sync write {name}"

        def run() -> None:
            port = self._live_port()
            self.stats.transactions += 1
            self._flush(port)
            self._send(port, wire.Request(self.protocol, wire.BROADCAST_ID, pk.SYNC_WRITE, params), what)

        with self.lock:
            self._guarded(what, run)
