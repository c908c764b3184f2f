"""A pty relay that sits between a driver and a device (a mock served on a pty, or real hardware) and
injects the faults of :mod:`tactile_rig.mocks.faults` into what the driver receives.

The relay opens the device's port (``upstream``) and offers its own pty; the driver opens
:attr:`PtyRelay.port`, a symlink to the relay's current ``/dev/pts/N`` that plays the part of a
``/dev/serial/by-id`` link. Bytes the driver writes go upstream untouched; bytes the device sends
go through a :class:`~tactile_rig.mocks.faults.FaultInjector` (``drop``, ``flip``, ``dup``,
``garbage`` per byte; ``split``, ``late``, ``stall``, ``unplug``, ``replug``, ``reboot`` per chunk)
in real time:

* ``unplug`` / ``replug``: the relay closes its pty (the driver's handle reads EIO, as when a USB
  adapter is pulled), removes the link for ``away_s`` / ``replug_s``, then offers a new pty under the
  same link and reopens the device's port, which resets an Arduino as plugging in a USB-powered
  board does.
* ``reboot``: the relay closes and reopens the device's port: a DTR edge, which resets the scale's
  Arduino and GRBL's. (A Dynamixel bus on an FTDI adapter does not reset on DTR: no effect there.)

Start it with :meth:`PtyRelay.start` or as a context manager; ``error`` holds what stopped its thread.
"""

from __future__ import annotations

import logging
import os
import pty
import select
import tempfile
import threading
import time
import tty
from collections import deque
from pathlib import Path

import serial

from tactile_rig.mocks.faults import FaultInjector
from tactile_rig.mocks.loop_thread import LoopThread
from tactile_rig.mocks.pty_server import read_master

log = logging.getLogger("tactile_rig.mocks.relay")

_POLL_S = 0.002
_SPLIT_GAP_S = 0.002  # the second half of a split chunk follows this much later (a separate read)


class PtyRelay(LoopThread):
    """Relay ``upstream`` (a device path) to a new pty at :attr:`port`, injecting ``faults``."""

    def __init__(self, upstream: str, faults: FaultInjector, *, baudrate: int, link_dir: str | None = None,
                 name: str = "device") -> None:
        self.upstream_path = upstream
        self.faults = faults
        self.baudrate = int(baudrate)
        self.name = name
        super().__init__(f"relay-{name}", log)
        self._dir = Path(link_dir or tempfile.mkdtemp(prefix="rigrelay-"))
        self.port = str(self._dir / f"{name}-relay")
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave_keep: int | None = None
        self._upstream: serial.Serial | None = None
        self._held: deque[tuple[float, bytes]] = deque()
        self._away_until: float | None = None
        self.unplugs = 0
        self.reboots = 0

    # -- lifecycle (start, stop, the context manager: LoopThread) ------------------------------------
    def _before_start(self) -> None:
        self._open_upstream()
        self._open_pty()

    def _after_stop(self) -> None:
        self._close_pty()
        self._close_upstream()
        try:
            os.rmdir(self._dir)
        except OSError:
            pass

    # -- the two sides ----------------------------------------------------------------------------
    def _open_upstream(self) -> None:
        self._upstream = serial.Serial(self.upstream_path, baudrate=self.baudrate, timeout=0)

    def _close_upstream(self) -> None:
        if self._upstream is not None:
            try:
                self._upstream.close()
            except (serial.SerialException, OSError):
                pass
            self._upstream = None

    def _open_pty(self) -> None:
        master, slave = pty.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master = master
        self._slave_keep = slave  # held so the master never sees EIO between the driver's opens
        tmp = f"{self.port}.tmp"
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)

    def _close_pty(self) -> None:
        try:
            os.unlink(self.port)
        except FileNotFoundError:
            pass
        for fd in (self._master, self._slave_keep):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave_keep = None

    # -- the loop ------------------------------------------------------------------------------------
    def _once(self) -> None:
        now = time.monotonic()
        if self._away_until is not None:
            if now < self._away_until:
                time.sleep(_POLL_S)
                return
            self._away_until = None
            self._open_upstream()  # the board powers up again: a reset
            self._open_pty()
            log.info("relay %s: plugged back in at %s", self.name, self.port)
            return
        assert self._master is not None and self._upstream is not None
        wait = _POLL_S
        if self._held:
            wait = max(0.0, min(wait, self._held[0][0] - now))
        readable, _, _ = select.select([self._master, self._upstream.fileno()], [], [], wait)
        if self._master in readable:
            data = read_master(self._master)  # None: the driver has the port closed for now
            if data:
                self._upstream.write(data)
        if self._upstream.fileno() in readable:
            data = self._upstream.read(self._upstream.in_waiting or 1)
            if data:
                self._from_device(data, time.monotonic())
        self._deliver(time.monotonic())

    def _from_device(self, data: bytes, now: float) -> None:
        fate = self.faults.chunk(data, now)
        if fate.reboot:
            self.reboots += 1
            self._close_upstream()  # a DTR edge: the Arduino resets
            self._open_upstream()
            return
        if fate.unplug_s is not None:
            self.unplugs += 1
            self._held.clear()
            self._close_pty()  # the driver's handle now reads EIO, and the link is gone
            self._close_upstream()
            self._away_until = now + fate.unplug_s
            log.info("relay %s: unplugged for %.3g s", self.name, fate.unplug_s)
            return
        if not fate.data:
            return
        if fate.split_at is not None:
            self._held.append((fate.release_s, fate.data[:fate.split_at]))
            self._held.append((fate.release_s + _SPLIT_GAP_S, fate.data[fate.split_at:]))
        else:
            self._held.append((fate.release_s, fate.data))

    def _deliver(self, now: float) -> None:
        while self._held and self._held[0][0] <= now and self._master is not None:
            _, data = self._held.popleft()
            view = memoryview(data)
            while view:
                try:
                    view = view[os.write(self._master, view):]
                except BlockingIOError:
                    select.select([], [self._master], [], 0.01)
