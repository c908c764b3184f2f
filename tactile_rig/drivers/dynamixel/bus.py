"""The Dynamixel bus on the real dynamixel-sdk: URLs, one lock per bus, typed errors.

:class:`UrlPortHandler` is the SDK's ``PortHandler`` opening its port with pyserial's
``serial_for_url`` so ``rigsim://`` and ``rigfault://`` URLs work as well as device paths.
:class:`DynamixelBus` wraps ``PacketHandler`` (Protocol 2.0 or 1.0) and the group helpers, holds
the bus lock for every transaction (the SDK's ``is_using`` flag is not a lock) and turns SDK
result codes into exceptions:

* ``COMM_RX_TIMEOUT`` → :class:`~tactile_rig.core.errors.DeviceTimeout` (wrong ID, baud, power)
* ``COMM_RX_CORRUPT`` → :class:`~tactile_rig.core.errors.LinkCorrupt` (noise, cut-off status; retryable)
* a status error number (P2) or command bit (P1) → :class:`CommandRejected` naming it
* the Alert bit (P2) or a hardware bit (P1) → :class:`~tactile_rig.core.errors.DeviceFault` with the
  decoded Hardware Error Status, for writes; reads still return their data while a fault is latched.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Iterable

import dynamixel_sdk as sdk

import tactile_rig.drivers.transport as transport
from tactile_rig.drivers.base import Driver
from tactile_rig.core.clock import Clock
from tactile_rig.core.errors import (
    CommandRejected,
    DeviceFault,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
    NotConnected,
    RigError,
)
from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.devices.dynamixel import error_codes as de

log = logging.getLogger("tactile_rig.dynamixel")



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

    ``lock`` is the bus lock of the port (shared with every tactile-rig driver on it): hold it
    around each SDK transaction when using the SDK directly from several threads.
    """

    def __init__(self, port_name: str) -> None:
        super().__init__(port_name)
        self.lock = transport.bus_lock(port_name)

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 - the SDK's name
        if self.is_open:
            self.closePort()
        self.ser = transport.open_serial(self.port_name, baudrate=self.baudrate, device=f"dynamixel@{self.port_name}",
                                         timeout_s=0)
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


class DynamixelBus(Driver):
    """One Dynamixel bus: a port at a baud rate speaking one protocol.

    ``port`` is a device path or a URL. Every method takes the bus lock, so drivers for several
    servos on one port may run in several threads.
    """

    def __init__(self, port: str, *, baudrate: int = 1_000_000, protocol: int = 2) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol={protocol!r} must be 1 or 2")
        self.port_name = port
        super().__init__(f"dynamixel@{port}")
        self.protocol = protocol
        self.baudrate = baudrate
        self.table = ct.TABLES[protocol]
        self.latency_timer_ms = check_latency_timer(port)
        self.port = UrlPortHandler(port)
        self.lock = self.port.lock
        self.packet = sdk.PacketHandler(float(protocol))
        with self.lock:
            if not self.port.setBaudRate(baudrate):
                raise ValueError(f"baudrate={baudrate} is not one the Dynamixel SDK supports "
                                 "(9600 ... 4000000, e.g. 57600 or 1000000)")
        self.clock: Clock = transport.port_clock(self.port.ser)
        #: last hardware error bits seen per ID (P2 Hardware Error Status layout)
        self.hardware_errors: dict[int, int] = {}

    def name(self, dxl_id: int) -> str:
        return f"dynamixel[{dxl_id}]@{self.port_name}"

    def _live_port(self) -> "UrlPortHandler":
        """The SDK's port, or ``NotConnected`` once the bus is closed (never the SDK's own exception)."""
        self.require_open()
        return self.port

    def _close(self) -> None:
        with self.lock:
            if self.port.is_open:
                self.port.closePort()

    # -- result handling -------------------------------------------------------------------------
    def _check_comm(self, dxl_id: int, result: int, what: str) -> None:
        if result == sdk.COMM_SUCCESS:
            return
        dev = self.name(dxl_id)
        if result == sdk.COMM_RX_TIMEOUT:
            raise DeviceTimeout(
                f"{what}: no status packet within the SDK's packet timeout (check the ID, the baud "
                f"rate {self.baudrate}, the power and, for a U2D2, the latency timer)", device=dev)
        if result == sdk.COMM_RX_CORRUPT:
            raise LinkCorrupt(f"{what}: corrupt or cut-off status packet (CRC/checksum mismatch)", device=dev)
        if result in (sdk.COMM_TX_FAIL, sdk.COMM_TX_ERROR, sdk.COMM_RX_FAIL):
            raise NotConnected(f"{what}: {self.packet.getTxRxResult(result)}", device=dev)
        if result == sdk.COMM_PORT_BUSY:
            raise RuntimeError(f"{dev}: {what}: port busy although the bus lock is held (a bug)")
        raise RigError(f"{what}: {self.packet.getTxRxResult(result)} (result {result})", device=dev)

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
                val, res, err = self.packet.read1ByteTxRx(self._live_port(), dxl_id, self.table["Hardware Error Status"].address)
                hw = val if res == sdk.COMM_SUCCESS else 0
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
    def ping(self, dxl_id: int) -> int:
        """The model number of ``dxl_id``."""
        with self.lock:
            model, result, error = self.packet.ping(self._live_port(), dxl_id)
            self._check_comm(dxl_id, result, "ping")
            self._check_status(dxl_id, error, "ping", fault_ok=True)
        return model

    def read_bytes(self, dxl_id: int, address: int, length: int, *, what: str | None = None) -> bytes:
        """``length`` raw bytes from ``address`` (allowed while a fault is latched)."""
        what = what or f"read {length} byte(s) at {address}"
        with self.lock:
            data, result, error = self.packet.readTxRx(self._live_port(), dxl_id, address, length)
            self._check_comm(dxl_id, result, what)
            self._check_status(dxl_id, error, what, fault_ok=True)
        return bytes(data)

    def write_bytes(self, dxl_id: int, address: int, data: bytes, *, what: str | None = None,
                    fault_ok: bool = False) -> None:
        """Write raw bytes; a latched fault raises DeviceFault unless ``fault_ok``."""
        what = what or f"write {len(data)} byte(s) at {address}"
        with self.lock:
            result, error = self.packet.writeTxRx(self._live_port(), dxl_id, address, len(data), list(data))
            self._check_comm(dxl_id, result, what)
            self._check_status(dxl_id, error, what, fault_ok=fault_ok)

    def read(self, dxl_id: int, name: str) -> int:
        """The value of control-table item ``name`` (signed items decoded)."""
        it = self.table[name]
        raw = int.from_bytes(self.read_bytes(dxl_id, it.address, it.size, what=f"read {name}"), "little")
        return it.from_raw(raw)

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
        """Send Reboot (clears a latched hardware error; RAM back to defaults, torque off)."""
        with self.lock:
            if self.protocol == 2:
                result, error = self.packet.reboot(self._live_port(), dxl_id)
            else:
                # The SDK's Protocol 1.0 handler has no reboot(); MX firmware accepts instruction 0x08.
                _, result, error = self.packet.txRxPacket(self._live_port(), [0xFF, 0xFF, dxl_id, 2, 0x08, 0])
            self._check_comm(dxl_id, result, "reboot")
            self.hardware_errors[dxl_id] = 0
            self._check_status(dxl_id, error & ~de.ALERT_BIT if self.protocol == 2 else error & de.P1_COMMAND_MASK,
                               "reboot", fault_ok=True)

    def factory_reset(self, dxl_id: int, option: int = 0x02) -> None:
        """Factory Reset (P2 option 0xFF all, 0x01 all but ID, 0x02 all but ID and baud)."""
        with self.lock:
            if self.protocol == 2:
                result, error = self.packet.factoryReset(self._live_port(), dxl_id, option)
            else:
                result, error = self.packet.factoryReset(self._live_port(), dxl_id)
            self._check_comm(dxl_id, result, "factory reset")
            self._check_status(dxl_id, error, "factory reset", fault_ok=True)

    def sync_read(self, ids: Iterable[int], name: str, *, fast: bool = False) -> dict[int, int]:
        """Item ``name`` of several IDs in one Sync Read (Protocol 2.0; ``fast``: Fast Sync Read)."""
        if self.protocol != 2:
            raise LimitError("Sync Read needs Protocol 2.0 (use bulk_read on Protocol 1.0)", device=self.port_name)
        it = self.table[name]
        ids = list(ids)
        with self.lock:
            group = sdk.GroupSyncRead(self._live_port(), self.packet, it.address, it.size)
            for i in ids:
                group.addParam(i)
            result = group.fastSyncRead() if fast else group.txRxPacket()
            self._check_comm(ids[0] if ids else 0xFE, result, f"sync read {name} of IDs {ids}")
            out = {}
            for i in ids:
                if not group.isAvailable(i, it.address, it.size):
                    raise LinkCorrupt(f"sync read {name}: no data for ID {i}", device=self.name(i))
                out[i] = it.from_raw(group.getData(i, it.address, it.size))
        return out

    def bulk_read(self, requests: Iterable[tuple[int, str]], *, fast: bool = False) -> dict[int, int]:
        """One item per ID in one Bulk Read: ``[(id, item name), ...]`` → {id: value}."""
        reqs = [(i, self.table[n]) for i, n in requests]
        if self.protocol == 1:
            return self._bulk_read_p1(reqs)
        with self.lock:
            group = sdk.GroupBulkRead(self._live_port(), self.packet)
            for i, it in reqs:
                if not group.addParam(i, it.address, it.size):
                    raise ValueError(f"bulk read: ID {i} is listed twice")
            result = group.fastBulkRead() if fast else group.txRxPacket()
            self._check_comm(reqs[0][0] if reqs else 0xFE, result, f"bulk read of IDs {[i for i, _ in reqs]}")
            out = {}
            for i, it in reqs:
                if not group.isAvailable(i, it.address, it.size):
                    raise LinkCorrupt(f"bulk read: no data for ID {i}", device=self.name(i))
                out[i] = it.from_raw(group.getData(i, it.address, it.size))
        return out

    def _bulk_read_p1(self, reqs: list[tuple[int, ct.Item]]) -> dict[int, int]:
        # SDK 4.1.0's GroupBulkRead passes a fast_option the Protocol 1.0 handler does not accept.
        param = [v for i, it in reqs for v in (it.size, i, it.address)]
        out = {}
        with self.lock:
            result = self.packet.bulkReadTx(self._live_port(), param, len(param))
            self._check_comm(reqs[0][0] if reqs else 0xFE, result, "bulk read")
            for i, it in reqs:
                data, result, error = self.packet.readRx(self._live_port(), i, it.size)
                self._check_comm(i, result, f"bulk read {it.name}")
                self._check_status(i, error, f"bulk read {it.name}", fault_ok=True)
                out[i] = it.from_raw(int.from_bytes(bytes(data), "little"))
        return out

    def sync_write(self, name: str, values: dict[int, int]) -> None:
        """Write item ``name`` of several IDs in one Sync Write (no status packets)."""
        it = self.table[name]
        with self.lock:
            group = sdk.GroupSyncWrite(self._live_port(), self.packet, it.address, it.size)
            for i, v in values.items():
                if not it.low <= int(v) <= it.high:
                    raise LimitError(f"{name}={v} is outside [{it.low}, {it.high}]", device=self.name(i))
                group.addParam(i, list(it.to_raw(int(v)).to_bytes(it.size, "little")))
            result = group.txPacket()
            self._check_comm(0xFE, result, f"sync write {name}")
