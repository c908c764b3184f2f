"""One validated exchange on a Dynamixel bus: the port, its loss and return, send, receive, resync, retry.

:class:`BusLink` holds the bus lock for every transaction (the SDK's ``is_using`` flag is not a
lock) and, per transaction:

1. flushes stale input (counted in :attr:`BusLink.stats`);
2. if an earlier request to the same ID failed (its status may still be in flight), first runs a
   *resync* read whose parameter length no in-flight status can have: once its answer arrives,
   every older status of that servo has arrived too (a servo answers in order) and was discarded;
3. sends the instruction through the SDK's ``PacketHandler.txPacket``;
4. receives with :class:`~tactile_rig.drivers.dynamixel.wire.StatusScanner` until the packet
   timeout (wire time + return delay + twice the adapter's latency timer): only a status from the
   request's ID with the parameter length the request implies is the answer; any other
   well-formed status is stale (discarded, counted), never returned.

A port that fails under a transaction (EIO: unplugged) is released and reopened with backoff by
the driver template (:class:`~tactile_rig.drivers.base.PortDriver`). The instructions themselves
(ping, reads, writes, reboot, group reads) and what a status's error byte means are
:class:`~tactile_rig.drivers.dynamixel.bus.DynamixelBus`'s.
"""

from __future__ import annotations

import errno
import logging
from dataclasses import dataclass
from typing import Callable, TypeVar

import dynamixel_sdk as sdk
import serial

import tactile_rig.drivers.dynamixel.wire as wire
import tactile_rig.drivers.transport as transport
from tactile_rig.core.clock import Clock, Deadline
from tactile_rig.core.deprecation import deprecated_alias
from tactile_rig.core.errors import DeviceTimeout, LinkCorrupt, NotConnected, RigError
from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.drivers.base import DriverStats, PortDriver
from tactile_rig.drivers.dynamixel.port import UrlPortHandler, check_latency_timer
from tactile_rig.drivers.reconnect import Reconnect

log = logging.getLogger("tactile_rig.dynamixel")

T = TypeVar("T")

_MAX_RETURN_DELAY_S = 254 * 2e-6  # Return Delay Time at its maximum (2 µs/unit)
_TIMEOUT_MARGIN_S = 0.002  # the SDK's 2 ms
_RESYNC_ADDRESS = 0  # Model Number: readable on both protocols, EEPROM, no side effects
#: a status later than this after its request failed is not guarded against by a resync
LATE_HORIZON_S = 1.0
#: resync reads use lengths 1..this (from address 0; gaps in the table read as zeros)
_RESYNC_MAX_LENGTH = 64


@dataclass
class BusStats(DriverStats):
    """What the bus saw on the wire since it opened (counters; the port's disconnects and
    reconnects are the driver template's)."""

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


class BusLink(PortDriver):
    """A port at a baud rate speaking one protocol, and one validated exchange on it at a time.

    ``port`` is a device path or URL. ``latency_timer_ms`` is the USB adapter's latency timer
    (FTDI default 16 ms; 1 ms after ``echo 1 > /sys/bus/usb-serial/devices/ttyUSBn/latency_timer``):
    the packet timeout allows twice it, and the value read from sysfs is used when it is larger.
    ``retries`` bounds the retries of idempotent reads; ``reconnect_policy`` is the backoff after
    an unplug.
    """

    stats: BusStats

    def __init__(self, port: str, *, baudrate: int, protocol: int, latency_timer_ms: float, retries: int,
                 reconnect_policy: Reconnect | None, exclusive: bool | None) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol={protocol!r} must be 1 or 2")
        if not latency_timer_ms >= 0:
            raise ValueError(f"latency_timer_ms={latency_timer_ms!r} must be >= 0 (FTDI: 1-255 ms)")
        if not 0 <= int(retries) <= 10:
            raise ValueError(f"retries={retries!r} must be in [0, 10]")
        self.port_name = port
        super().__init__(f"dynamixel@{port}", reconnect_port=port, stats=BusStats())
        self.protocol = protocol
        self.baudrate = baudrate
        self.table = ct.TABLES[protocol]
        self.retries = int(retries)
        measured = check_latency_timer(port)
        #: the latency timer the packet timeout allows for (ms)
        self.latency_timer_ms = max(float(latency_timer_ms), float(measured or 0))
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
        self.reconnect_policy = reconnect_policy if reconnect_policy is not None else Reconnect(self.clock)

    reconnect = deprecated_alias("reconnect_policy")

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
        if self.reconnect_policy is not None and self.reconnect_policy.away:
            self._ensure_port()
        elif not self.port.is_open:
            raise NotConnected(f"port {self.port_name!r} is not open", device=self.device)
        return self.port

    def _lost(self, exc: BaseException, what: str) -> NotConnected:
        """The port failed under us: release it (freeing the SDK's ``is_using``), start reconnecting."""
        why = "unplugged (EIO)" if getattr(exc, "errno", None) == errno.EIO else (str(exc) or type(exc).__name__)
        self._port_lost(why)
        log.warning("%s: %s: port failed: %s", self.device, what, why)
        return NotConnected(f"{what}: port {self.port_name!r} failed: {why}; the bus reconnects when it returns",
                            device=self.device)

    def _reopen(self) -> None:
        self.port.setupPort(self.baudrate)

    def _release_port(self) -> None:
        self.port.closePort()

    def _on_port_lost(self, reason: str) -> None:
        self._in_flight.clear()

    def _on_port_back(self) -> None:
        self.clock = transport.port_clock(self.port.ser)
        if self.reconnect_policy is not None:
            self.reconnect_policy.clock = self.clock
        self._in_flight.clear()
        log.info("%s: port is back, reopened", self.device)

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

    def _begin(self, port: UrlPortHandler, ids: list[int], what: str) -> None:
        """Start a transaction: first settle any ID whose last answer never came (so a late status
        cannot answer this request), then drop stale input."""
        self.stats.transactions += 1
        for i in ids:
            if i in self._in_flight:
                self._resync(port, i, what)
        self._flush(port)
