"""The Dynamixel port: dynamixel-sdk's ``PortHandler`` opening paths and pyserial URLs, and the FTDI latency timer.

:class:`UrlPortHandler` is the SDK's ``PortHandler`` opening its port with pyserial's
``serial_for_url`` (through :func:`tactile_rig.drivers.transport.open_serial`), so ``rigsim://`` and
``rigfault://`` URLs work as well as device paths, and a device path is opened exclusively.
:func:`check_latency_timer` reads a USB adapter's latency timer from sysfs, the most common cause of
slow or missing status packets.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import dynamixel_sdk as sdk
import serial

import tactile_rig.drivers.transport as transport
from tactile_rig.core.errors import NotConnected, PortInUse

log = logging.getLogger("tactile_rig.dynamixel")

#: the SDK's own assumption for the FTDI latency timer (ms); a U2D2 ships with 16
DEFAULT_LATENCY_TIMER_MS = 16.0


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
