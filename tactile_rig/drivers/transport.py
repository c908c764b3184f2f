"""The serial transport every driver talks through.

A port is a device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, a pty ``/dev/pts/N``) or a
pyserial URL (``rigsim://dynamixel?ids=1``, ``rigfault://rigsim://scale#drop=0.01``, ``spy://...``,
``loop://``). :class:`SerialTransport` adds what pyserial lacks: a monotonic deadline for multi-read
transactions (:meth:`read_exact`), one lock per bus shared by every driver on the same port,
typed errors that name the device, and a DEBUG log of every byte exchanged.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
from pathlib import Path
from typing import Any

import serial

from tactile_rig.core.clock import Clock, Deadline, RealClock
from tactile_rig.core.errors import DeviceTimeout, NotConnected, PortInUse

log = logging.getLogger("tactile_rig.transport")

_BUS_LOCKS: dict[str, threading.RLock] = {}
_BUS_LOCKS_GUARD = threading.Lock()


def bus_lock(port: str) -> threading.RLock:
    """The one re-entrant lock of the bus on ``port`` (shared by every driver on that port)."""
    with _BUS_LOCKS_GUARD:
        return _BUS_LOCKS.setdefault(port, threading.RLock())


def is_device_path(port: str) -> bool:
    """True for a device path (``/dev/ttyUSB0``, a pty), False for a pyserial URL (``rigsim://...``)."""
    return "://" not in port


def stable_port_path(port: str, by_id_dir: str | os.PathLike[str] = "/dev/serial/by-id") -> str:
    """The ``/dev/serial/by-id`` link of ``port`` if there is one (survives re-enumeration), else ``port``."""
    if "://" in port or not os.path.exists(port):
        return port
    real = os.path.realpath(port)
    folder = Path(by_id_dir)
    if folder.is_dir():
        for link in sorted(folder.iterdir()):
            if os.path.realpath(link) == real:
                return str(link)
    return port


def open_serial(port: str, *, baudrate: int, device: str, timeout_s: float | None = 0.0,
                log_bytes: bool | None = None, **kwargs: Any) -> serial.SerialBase:
    """Open ``port`` (path or URL) with pyserial's ``serial_for_url``; errors become :class:`NotConnected`.

    A device path is opened exclusively (an advisory ``flock``, as pyserial's ``exclusive=True``
    takes it): a second handle on the same port, in this process or another, gets
    :class:`PortInUse` naming the port instead of silently sharing (and stealing) its bytes.

    ``log_bytes`` (default: when the ``tactile_rig.transport`` logger is at DEBUG at open time)
    returns the port wrapped in :class:`ByteLog`, so every byte any client of the port writes or
    reads (the Dynamixel SDK's ``PortHandler`` included) is logged with ``device``.
    """
    if is_device_path(port) and os.name == "posix":
        kwargs.setdefault("exclusive", True)
    try:
        ser = serial.serial_for_url(port, baudrate=baudrate, timeout=timeout_s, **kwargs)
    except (serial.SerialException, OSError, ValueError) as exc:
        code = getattr(exc, "errno", None)
        if kwargs.get("exclusive") and (code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES)
                                        or "exclusively lock" in str(exc)):
            raise PortInUse(f"port {port!r} is already in use (another program or driver holds it open); "
                            f"close it there first", device=device, port=port) from exc
        raise NotConnected(
            f"cannot open port {port!r} at {baudrate} baud: {exc} "
            "(check the path, that the device is plugged in, and the permissions on the port)",
            device=device,
        ) from exc
    if log_bytes if log_bytes is not None else log.isEnabledFor(logging.DEBUG):
        return ByteLog(ser, device)
    return ser


class ByteLog:
    """A pyserial port that logs every byte written and read (``DEVICE TX/RX hex``) at DEBUG on
    ``tactile_rig.transport``; everything else is the port's own (attributes read and set through)."""

    def __init__(self, ser: Any, device: str) -> None:
        object.__setattr__(self, "_ser", ser)
        object.__setattr__(self, "_device", device)

    def write(self, data: bytes) -> int | None:
        log.debug("%s TX %s", self._device, bytes(data).hex(" "))
        return self._ser.write(data)

    def read(self, size: int = 1) -> bytes:
        data = self._ser.read(size)
        if data:
            log.debug("%s RX %s", self._device, bytes(data).hex(" "))
        return data

    def __getattr__(self, name: str) -> Any:
        return getattr(self._ser, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self._ser, name, value)

    def __enter__(self) -> "ByteLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self._ser.close()


def port_clock(ser: Any) -> Clock:
    """The clock a port runs on: the mock's clock for ``rigsim://`` ports, else wall time."""
    clock = getattr(ser, "clock", None)
    return clock if clock is not None else RealClock()


class SerialTransport:
    """A serial port with deadlines, a bus lock, typed errors and byte logging.

    ``port`` is a path or URL (opened here) or an already open pyserial object. ``device`` names the
    device in errors and logs. The transport's clock is the port's own (virtual for in-process mocks)
    unless given.
    """

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        baudrate: int = 115200,
        device: str = "serial",
        clock: Clock | None = None,
        **serial_kwargs: Any,
    ) -> None:
        if isinstance(port, str):
            self.port_name = port
            # This class logs its own bytes (with the reads it makes), so the port is not wrapped.
            self.serial = open_serial(port, baudrate=baudrate, device=device, log_bytes=False, **serial_kwargs)
        else:
            self.serial = port
            self.port_name = str(getattr(port, "portstr", None) or getattr(port, "port", "serial"))
        self.device = device
        self.clock: Clock = clock if clock is not None else port_clock(self.serial)
        self.lock = bus_lock(self.port_name)

    # -- basic I/O -------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        """Write all of ``data``; a vanished port raises :class:`NotConnected`."""
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s TX %s", self.device, data.hex(" "))
        try:
            self.serial.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._disconnected(exc) from exc

    def read_available(self) -> bytes:
        """Return whatever bytes are already waiting (possibly none), without blocking."""
        try:
            n = self.serial.in_waiting
            if not n:
                return b""
            self.serial.timeout = 0
            data = self.serial.read(n)
        except (serial.SerialException, OSError) as exc:
            raise self._disconnected(exc) from exc
        if data and log.isEnabledFor(logging.DEBUG):
            log.debug("%s RX %s", self.device, data.hex(" "))
        return data

    def read_some(self, max_bytes: int, timeout_s: float) -> bytes:
        """Read up to ``max_bytes``, waiting at most ``timeout_s`` for the first ones."""
        try:
            self.serial.timeout = max(0.0, timeout_s)
            data = self.serial.read(max_bytes)
        except (serial.SerialException, OSError) as exc:
            raise self._disconnected(exc) from exc
        if data and log.isEnabledFor(logging.DEBUG):
            log.debug("%s RX %s", self.device, data.hex(" "))
        return data

    def read_exact(self, n: int, deadline: Deadline | float) -> bytes:
        """Read exactly ``n`` bytes before ``deadline`` (a :class:`Deadline` or seconds from now).

        Raises :class:`DeviceTimeout` (with the bytes received so far in ``.partial``) when the
        deadline passes first.
        """
        dl = deadline if isinstance(deadline, Deadline) else Deadline(self.clock, deadline)
        buf = bytearray()
        while len(buf) < n:
            remaining = dl.remaining_s()
            chunk = self.read_some(n - len(buf), 0.0 if remaining is None else remaining)
            buf += chunk
            if len(buf) < n and dl.expired():
                err = DeviceTimeout(
                    f"expected {n} bytes within {dl.timeout_s:.4g} s, got {len(buf)}"
                    + (f" ({bytes(buf).hex(' ')})" if buf else " (no answer)"),
                    device=self.device,
                )
                err.partial = bytes(buf)  # type: ignore[attr-defined]
                raise err
        return bytes(buf)

    def read_until(self, terminator: bytes, deadline: Deadline | float, max_bytes: int = 4096) -> bytes:
        """Read up to and including ``terminator`` before the deadline; raise DeviceTimeout otherwise."""
        dl = deadline if isinstance(deadline, Deadline) else Deadline(self.clock, deadline)
        buf = bytearray()
        while not buf.endswith(terminator):
            if len(buf) >= max_bytes:
                raise DeviceTimeout(
                    f"no {terminator!r} within {max_bytes} bytes", device=self.device
                )
            remaining = dl.remaining_s()
            buf += self.read_some(1, 0.0 if remaining is None else remaining)
            if dl.expired() and not buf.endswith(terminator):
                err = DeviceTimeout(
                    f"expected a line ending in {terminator!r} within {dl.timeout_s:.4g} s, got "
                    f"{bytes(buf)!r}",
                    device=self.device,
                )
                err.partial = bytes(buf)  # type: ignore[attr-defined]
                raise err
        return bytes(buf)

    def reset_input_buffer(self) -> bytes:
        """Discard (and return, for the log) stale input, e.g. a late reply to a timed-out request."""
        stale = self.read_available()
        try:
            self.serial.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise self._disconnected(exc) from exc
        if stale:
            log.debug("%s flushed %d stale bytes", self.device, len(stale))
        return stale

    def set_baudrate(self, baudrate: int) -> None:
        self.serial.baudrate = baudrate

    @property
    def is_open(self) -> bool:
        return bool(getattr(self.serial, "is_open", False))

    def close(self) -> None:
        try:
            self.serial.close()
        except (serial.SerialException, OSError):  # already gone: closing must not fail
            pass

    def __enter__(self) -> "SerialTransport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _disconnected(self, exc: BaseException) -> NotConnected:
        code = getattr(exc, "errno", None)
        why = "unplugged (EIO)" if code == errno.EIO else str(exc)
        return NotConnected(f"port {self.port_name!r} failed: {why}", device=self.device)
