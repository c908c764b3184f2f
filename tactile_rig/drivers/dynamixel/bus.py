"""The Dynamixel bus: dynamixel-sdk sends, :mod:`.wire` checks every status packet, typed errors.

:class:`UrlPortHandler` is the SDK's ``PortHandler`` opening its port with pyserial's
``serial_for_url`` so ``rigsim://`` and ``rigfault://`` URLs work as well as device paths (a device
path is opened exclusively). :class:`DynamixelBus` holds the bus lock for every transaction (the
SDK's ``is_using`` flag is not a lock) and, per transaction:

1. flushes stale input (counted in :attr:`DynamixelBus.stats`);
2. if an earlier request to the same ID failed (its status may still be in flight), first runs a
   *resync* read whose parameter length no in-flight status can have: once its answer arrives,
   every older status of that servo has arrived too (a servo answers in order) and was discarded;
3. sends the instruction through the SDK's ``PacketHandler.txPacket``;
4. receives with :class:`~tactile_rig.drivers.dynamixel.wire.StatusScanner` until the packet
   timeout (wire time + return delay + twice the adapter's latency timer): only a status from the
   request's ID with the parameter length the request implies is the answer; any other
   well-formed status is stale (discarded, counted), never returned.

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

import errno
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterable, TypeVar

import dynamixel_sdk as sdk
import serial

import tactile_rig.drivers.transport as transport
from tactile_rig.core.clock import Clock, Deadline
from tactile_rig.core.errors import (
    CommandRejected,
    DeviceFault,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
    NotConnected,
    PortInUse,
    RigError,
)
from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.drivers.base import Driver
import tactile_rig.drivers.dynamixel.wire as wire
from tactile_rig.drivers.reconnect import Reconnect

log = logging.getLogger("tactile_rig.dynamixel")

T = TypeVar("T")

#: the SDK's own assumption for the FTDI latency timer (ms); a U2D2 ships with 16
DEFAULT_LATENCY_TIMER_MS = 16.0
_MAX_RETURN_DELAY_S = 254 * 2e-6  # Return Delay Time at its maximum (2 µs/unit)
_TIMEOUT_MARGIN_S = 0.002  # the SDK's 2 ms
_RESYNC_ADDRESS = 0  # Model Number: readable on both protocols, EEPROM, no side effects
#: a status later than this after its request failed is not guarded against by a resync
LATE_HORIZON_S = 1.0
#: resync reads use lengths 1..this (from address 0; gaps in the table read as zeros)
_RESYNC_MAX_LENGTH = 64


def check_latency_timer(port: str, *, sysfs_root: str | Path = "/sys") -> int | None:
    """The FTDI latency timer (ms) of ``port`` if it is a USB serial adapter, else None.

    Logs a warning when it is not 1 ms: at the default 16 ms a status packet can take 16-32 ms,
    the most common cause of slow or missing status packets with a U2D2.
    """
    if "://" in port:
        return None
    name = os.path.basename(os.path.realpath(port))
    path = Path(sysfs_root) / "bus" / "usb-serial" / "devices" / name / "latency_timer"
    try:
        ms = int(path.read_text().strip())
    except (OSError, ValueError):
        return None
    if ms != 1:
        log.warning(
            "%s: FTDI latency timer is %d ms (expected 1 ms); status packets will be slow or time out. "
            "Fix: echo 1 | sudo tee %s", port, ms, path)
    return ms


class UrlPortHandler(sdk.PortHandler):
    """The SDK's PortHandler, opening paths and pyserial URLs (``rigsim://``, ``rigfault://``).

    A device path is opened exclusively (``exclusive=None``: paths yes, URLs no), so a second
    process opening the same gripper port gets :class:`PortInUse` instead of silently stealing
    the bytes. ``lock`` is the bus lock of the port (shared with every tactile-rig driver on it):
    hold it around each SDK transaction when using the SDK directly from several threads.
    """

    is_open: bool
    is_using: bool

    def __init__(self, port_name: str, *, exclusive: bool | None = None) -> None:
        super().__init__(port_name)
        self.lock = transport.bus_lock(port_name)
        self.exclusive = ("://" not in port_name) if exclusive is None else bool(exclusive)

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 - the SDK's name
        if self.is_open:
            self.closePort()
        device = f"dynamixel@{self.port_name}"
        kwargs = {"exclusive": True} if self.exclusive else {}
        try:
            self.ser = transport.open_serial(self.port_name, baudrate=self.baudrate, device=device, timeout_s=0,
                                             **kwargs)
        except NotConnected as exc:
            cause = exc.__cause__
            if self.exclusive and cause is not None and "exclusively lock" in str(cause):
                raise PortInUse(f"port {self.port_name!r} is already in use by another process or handle "
                                "(it is opened exclusively); close the other user or share one DynamixelBus",
                                device=device, port=self.port_name) from cause
            raise
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def closePort(self) -> None:  # noqa: N802 - the SDK's name
        """Close; a port that already vanished closes quietly."""
        try:
            if self.ser is not None:
                self.ser.close()
        except (serial.SerialException, OSError):
            pass
        self.is_open = False
        self.is_using = False


@dataclass
class BusStats:
    """What the bus saw on the wire since it opened (counters)."""

    transactions: int = 0
    stale_bytes: int = 0  #: flushed before a transaction
    stale_packets: int = 0  #: well-formed status packets that were not the answer (discarded)
    corrupt_packets: int = 0  #: CRC/checksum failures
    foreign_packets: int = 0  #: well-formed non-status packets (echoes)
    skipped_bytes: int = 0  #: bytes that could not start a packet
    timeouts: int = 0
    retries: int = 0
    resyncs: int = 0
    writes_confirmed_by_readback: int = 0  #: writes whose status was lost but whose value read back
    writes_repeated_after_readback: int = 0  #: writes read back as not applied, then sent again
    verify_mismatches: int = 0  #: read-verify pairs that disagreed
    implausible_values: int = 0  #: reads of a writable item outside its range (damaged, read again)
    disconnects: int = 0
    reconnects: int = 0

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


class DynamixelBus(Driver):
    """One Dynamixel bus: a port at a baud rate speaking one protocol.

    ``port`` is a device path or a URL. Every method takes the bus lock, so drivers for several
    servos on one port may run in several threads.

    ``latency_timer_ms`` is the USB adapter's latency timer (FTDI default 16 ms; 1 ms after
    ``echo 1 > /sys/bus/usb-serial/devices/ttyUSBn/latency_timer``): the packet timeout allows
    twice it, and the value read from sysfs is used when it is larger. ``retries`` bounds the
    retries of idempotent reads. ``reconnect`` is the backoff policy after an unplug.
    """

    def __init__(self, port: str, *, baudrate: int = 1_000_000, protocol: int = 2,
                 latency_timer_ms: float = DEFAULT_LATENCY_TIMER_MS, retries: int = 2,
                 reconnect: Reconnect | None = None, exclusive: bool | None = None) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol={protocol!r} must be 1 or 2")
        if not latency_timer_ms >= 0:
            raise ValueError(f"latency_timer_ms={latency_timer_ms!r} must be >= 0 (FTDI: 1-255 ms)")
        if not 0 <= int(retries) <= 10:
            raise ValueError(f"retries={retries!r} must be in [0, 10]")
        self.port_name = port
        super().__init__(f"dynamixel@{port}")
        self.protocol = protocol
        self.baudrate = baudrate
        self.table = ct.TABLES[protocol]
        self.retries = int(retries)
        measured = check_latency_timer(port)
        #: the latency timer the packet timeout allows for (ms)
        self.latency_timer_ms = max(float(latency_timer_ms), float(measured or 0))
        self.stats = BusStats()
        #: ID → {status parameter count: when its request failed} for statuses that may still come
        self._in_flight: dict[int, dict[int, float]] = {}
        self.port = UrlPortHandler(port, exclusive=exclusive)
        self.lock = self.port.lock
        self.packet = sdk.PacketHandler(float(protocol))
        with self.lock:
            if not self.port.setBaudRate(baudrate):
                raise ValueError(f"baudrate={baudrate} is not one the Dynamixel SDK supports "
                                 "(9600 ... 4000000, e.g. 57600 or 1000000)")
        self.clock: Clock = transport.port_clock(self.port.ser)
        self.reconnect = reconnect if reconnect is not None else Reconnect(self.clock)
        #: last hardware error bits seen per ID (P2 Hardware Error Status layout)
        self.hardware_errors: dict[int, int] = {}

    def name(self, dxl_id: int) -> str:
        return f"dynamixel[{dxl_id}]@{self.port_name}"

    def packet_timeout_s(self, tx_bytes: int, rx_bytes: int) -> float:
        """How long to wait for a status: both packets' wire time, the longest Return Delay Time,
        twice the latency timer (the adapter may hold the first and the last bytes) and 2 ms."""
        wire_s = (tx_bytes + rx_bytes) * 10.0 / self.baudrate
        return wire_s + _MAX_RETURN_DELAY_S + 2.0 * self.latency_timer_ms / 1000.0 + _TIMEOUT_MARGIN_S

    # -- the port, its loss and its return ---------------------------------------------------------
    def _live_port(self) -> UrlPortHandler:
        """The open port; ``NotConnected`` once closed or while the device is away (reopening it
        when the reconnect policy says it is time)."""
        self.require_open()
        if self.reconnect.away:
            if not self.reconnect.due():
                raise self.reconnect.not_connected(self.device, self.port_name)
            try:
                self.port.setupPort(self.baudrate)
            except NotConnected as exc:
                self.port.is_open = False
                self.reconnect.failed(str(exc))
                raise self.reconnect.not_connected(self.device, self.port_name) from exc
            self.reconnect.succeeded()
            self.stats.reconnects += 1
            self.clock = transport.port_clock(self.port.ser)
            self.reconnect.clock = self.clock
            self._in_flight.clear()
            log.info("%s: port is back, reopened", self.device)
        elif not self.port.is_open:
            raise NotConnected(f"port {self.port_name!r} is not open", device=self.device)
        return self.port

    def _lost(self, exc: BaseException, what: str) -> NotConnected:
        """The port failed under us: close it, free the SDK's ``is_using``, start reconnecting."""
        why = "unplugged (EIO)" if getattr(exc, "errno", None) == errno.EIO else (str(exc) or type(exc).__name__)
        self.port.closePort()
        self._in_flight.clear()
        self.stats.disconnects += 1
        self.reconnect.lost(why)
        log.warning("%s: %s: port failed: %s", self.device, what, why)
        return NotConnected(f"{what}: port {self.port_name!r} failed: {why}; the bus reconnects when it returns",
                            device=self.device)

    def _close(self) -> None:
        with self.lock:
            self.port.closePort()

    def _guarded(self, what: str, fn: Callable[[], T]) -> T:
        """Run ``fn`` (a wire exchange, bus lock held); a vanished port becomes ``NotConnected``."""
        try:
            return fn()
        except RigError:
            raise
        except (serial.SerialException, OSError) as exc:
            raise self._lost(exc, what) from exc
        finally:
            self.port.is_using = False

    # -- one transaction ---------------------------------------------------------------------------
    def _flush(self, port: UrlPortHandler) -> None:
        ser = port.ser
        n = ser.in_waiting
        if n:
            stale = ser.read(n)
            self.stats.stale_bytes += len(stale)
            log.debug("%s: flushed %d stale byte(s): %s", self.device, len(stale), stale.hex(" "))
        ser.reset_input_buffer()

    def _send(self, port: UrlPortHandler, req: wire.Request, what: str) -> int:
        """Send ``req`` through the SDK (its framing, stuffing and CRC); return the bytes sent."""
        n = len(req.params)
        if self.protocol == 2 and b"\xff\xff\xfd" in bytes([req.instruction]) + req.params:
            # SDK 4.1.0's addStuffing rebinds its argument and so sends such a packet unstuffed
            raw = wire.encode_instruction_p2(req.dxl_id, req.instruction, req.params)
            port.clearPort()
            if port.writePort(raw) != len(raw):
                raise NotConnected(f"{what}: the port took only part of the packet", device=self.name(req.dxl_id))
            return len(raw)
        if self.protocol == 2:
            tx = [0] * (10 + n)
            tx[4], tx[5], tx[6], tx[7] = req.dxl_id, (n + 3) & 0xFF, (n + 3) >> 8, req.instruction
            tx[8:8 + n] = req.params
        else:
            tx = [0] * (6 + n)
            tx[2], tx[3], tx[4] = req.dxl_id, n + 2, req.instruction
            tx[5:5 + n] = req.params
        port.is_using = False
        result = self.packet.txPacket(port, tx)
        port.is_using = False
        if result != sdk.COMM_SUCCESS:
            raise NotConnected(f"{what}: {self.packet.getTxRxResult(result)}", device=self.name(req.dxl_id))
        return len(tx)

    def _receive(self, port: UrlPortHandler, req: wire.Request, tx_bytes: int, what: str, *,
                 exact: bool = False) -> wire.StatusPacket:
        """The status answering ``req``; stale packets are discarded. ``exact``: no parameterless
        rejection accepted (the resync read)."""
        n = req.expected_params or 0
        # a status longer than ours or any still in flight is corruption, not worth waiting for
        longest = max([n, 3] + [k for lengths in self._in_flight.values() for k in lengths])
        scanner = wire.StatusScanner(self.protocol, max_params=longest)
        timeout_s = self.packet_timeout_s(tx_bytes, n + (11 if self.protocol == 2 else 6))
        deadline = Deadline(self.clock, timeout_s)
        corrupt = 0
        ser = port.ser
        dev = self.name(req.dxl_id)
        try:
            while True:
                ser.timeout = deadline.remaining_s() or 0.0
                chunk = ser.read(scanner.bytes_wanted())
                for ev in scanner.feed(chunk):
                    if isinstance(ev, wire.StatusPacket):
                        why = wire.mismatch(req, ev)
                        if why is None and exact and len(ev.params) != n:
                            why = f"{len(ev.params)} parameter byte(s), expected exactly {n}"
                        if why is None:
                            self._in_flight.pop(req.dxl_id, None)
                            return ev
                        self.stats.stale_packets += 1
                        log.debug("%s: %s: discarded a stale status (%s): %s", dev, what, why, ev.raw.hex(" "))
                    elif isinstance(ev, wire.Corrupt):
                        corrupt += 1
                        self.stats.corrupt_packets += 1
                    else:
                        self.stats.foreign_packets += 1
                if deadline.expired():
                    break
        finally:
            ser.timeout = 0
            self.stats.skipped_bytes += scanner.skipped
        # Our status may still come, late: the next request to this ID resyncs first (a fast
        # read's caller marks its servos instead: a broadcast ID cannot be resynced).
        if req.dxl_id != wire.BROADCAST_ID:
            self._expect_late(req.dxl_id, n)
        if corrupt or scanner.pending:
            partial = f" ({len(scanner.pending)} byte(s) of a cut-off packet)" if scanner.pending else ""
            raise LinkCorrupt(f"{what}: corrupt or cut-off status packet{partial}; "
                              f"{corrupt} CRC/checksum failure(s)", device=dev)
        self.stats.timeouts += 1
        raise DeviceTimeout(
            f"{what}: no status packet within {timeout_s * 1000:.3g} ms (check the ID, the baud "
            f"rate {self.baudrate}, the power and, for a U2D2, the latency timer: {self.latency_timer_ms:g} ms "
            "allowed)", device=dev)

    def _expect_late(self, dxl_id: int, n_params: int) -> None:
        """A request to ``dxl_id`` failed: its status (or a parameterless rejection) may still come."""
        now = self.clock.now_s()
        self._in_flight.setdefault(dxl_id, {}).update({n_params: now, 0: now})

    def _resync(self, port: UrlPortHandler, dxl_id: int, what: str) -> None:
        """Read a length no in-flight status of ``dxl_id`` has; when it arrives the line is clean."""
        busy = self._in_flight.get(dxl_id, {})
        now = self.clock.now_s()
        for k in [k for k, t in busy.items() if now - t > LATE_HORIZON_S]:
            del busy[k]  # a status this late is not waited for any more
        length = next((k for k in range(1, min(self.table.size, _RESYNC_MAX_LENGTH) + 1) if k not in busy), None)
        if length is None:
            # Every length is in flight (a dead line, many fast timeouts): the oldest of those
            # statuses is the least likely to come at all; reuse its length.
            length = min((k for k in busy if k), key=lambda k: busy[k])
            del busy[length]
        req = wire.Request(self.protocol, dxl_id, wire.READ, self._read_params(_RESYNC_ADDRESS, length))
        self.stats.resyncs += 1
        self._flush(port)
        sent = self._send(port, req, what)
        self._receive(port, req, sent, f"{what} (resync)", exact=True)
        self._in_flight.pop(dxl_id, None)

    def _txrx(self, req: wire.Request, what: str) -> wire.StatusPacket:
        """One validated exchange (bus lock held; no retry)."""
        def run() -> wire.StatusPacket:
            port = self._live_port()
            self._begin(port, [req.dxl_id], what)
            sent = self._send(port, req, what)
            return self._receive(port, req, sent, what)
        return self._guarded(what, run)

    def _retrying(self, fn: Callable[[], T]) -> T:
        """Call an idempotent ``fn`` up to 1 + ``retries`` times on DeviceTimeout / LinkCorrupt."""
        first: DeviceTimeout | LinkCorrupt | None = None
        for attempt in range(self.retries + 1):
            try:
                return fn()
            except (DeviceTimeout, LinkCorrupt) as exc:
                first = first or exc
                if attempt == self.retries:
                    # the first failure says what went wrong; the retries only confirm it
                    raise first from (exc if exc is not first else None)
                self.stats.retries += 1
        raise AssertionError("unreachable")

    def _read_params(self, address: int, length: int) -> bytes:
        if self.protocol == 2:
            return bytes([address & 0xFF, address >> 8, length & 0xFF, length >> 8])
        return bytes([address, length])

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

    def _begin(self, port: UrlPortHandler, ids: list[int], what: str) -> None:
        """Start a transaction: first settle any ID whose last answer never came (so a late status
        cannot answer this request), then drop stale input."""
        self.stats.transactions += 1
        for i in ids:
            if i in self._in_flight:
                self._resync(port, i, what)
        self._flush(port)

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
            raw = self._group_read(0x82, params, reqs, f"sync read {name}")
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
            raw = self._group_read(0x92, params, group, "bulk read")
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
            self._send(port, wire.Request(self.protocol, wire.BROADCAST_ID, 0x83, params), what)

        with self.lock:
            self._guarded(what, run)
