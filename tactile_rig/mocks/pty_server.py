"""Serve a :class:`~tactile_rig.mocks.serial_device.SerialDevice` on a pseudo-terminal pair.

Any client opens the slave path (``/dev/pts/N``) as it would a USB serial adapter: the real
dynamixel-sdk, grbl-streamer, pyserial, a terminal. The server runs its own thread in real time:
it notices the client opening and closing the port (the master reads EIO while no client holds the
slave), reads the client's baud rate from the terminal settings (a mismatch garbles the bytes, as
on a real line), feeds the device and writes its output when the device's wire timing says the last
byte has arrived.

The line rate is read when each chunk crosses the "wire", not once at open: a client opens the
port at the pty's current rate (38400, or whatever the previous client left) and sets its own, then
flushes its input, a moment later, as pyserial does. An Uno's bootloader covers that moment on real
hardware (the sketch starts ~0.5 s after the DTR reset); here a device that resets on open (its
``open_hold_s`` attribute, e.g. the GRBL mock's) has its output held that long, and every device's
output until the client's rate matches (at most ``SETTLE_S``), so a client that configures the port
right after opening never sees a garbled or flushed banner. A Dynamixel bus (an FTDI adapter, no
reset) answers at once.

A close and reopen quicker than the server's poll leaves no EIO to see; on Linux the server also
watches the slave path with inotify, so such a reopen still resets the device (a DTR edge resets an
Uno however quickly the port is reopened).
"""

from __future__ import annotations

import ctypes
import errno
import logging
import os
import pty
import random
import select
import struct
import termios
import time
import tty

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.mocks.loop_thread import LoopThread
from tactile_rig.mocks.serial_device import SerialDevice

log = logging.getLogger("tactile_rig.mocks.pty")

_BAUD_BY_CONSTANT = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if name.startswith("B") and name[1:].isdigit()
}

# Below this much time to the next output we spin instead of sleeping in select(). With the
# server thread's timer slack at 1 µs (see _on_thread_start) a select() wake-up is only a few
# tens of µs late, so a short spin suffices and the server leaves the CPU to the client.
_SPIN_S = 0.0001
_PR_SET_TIMERSLACK = 29  # linux/prctl.h
_IDLE_POLL_S = 0.005
_CLOSED_POLL_S = 0.002
SETTLE_S = 0.25  # longest wait after an open for the client to set its line rate

# linux/inotify.h
_IN_OPEN, _IN_CLOSE_WRITE, _IN_CLOSE_NOWRITE = 0x20, 0x08, 0x10
_IN_NONBLOCK, _IN_CLOEXEC = 0o4000, 0o2000000
_EVENT_HEADER = struct.Struct("iIII")


def read_master(fd: int) -> bytes | None:
    """What a pty master ``fd`` (non-blocking) has to read now (``b""``: nothing yet), or None while
    no client holds the slave open (the master reads EIO then)."""
    try:
        return os.read(fd, 4096)
    except BlockingIOError:
        return b""
    except OSError as exc:
        if exc.errno == errno.EIO:
            return None
        raise


class _OpenCloseWatch:
    """Counts the opens and closes of a path (Linux inotify); inert where inotify is unavailable."""

    def __init__(self, path: str) -> None:
        self.fd: int | None = None
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            fd = libc.inotify_init1(_IN_NONBLOCK | _IN_CLOEXEC)
            if fd < 0:
                return
            if libc.inotify_add_watch(fd, path.encode(), _IN_OPEN | _IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE) < 0:
                os.close(fd)
                return
            self.fd = fd
        except (OSError, AttributeError):  # not Linux
            self.fd = None

    def drain(self) -> list[int]:
        """The opens (+1) and closes (-1) of the path since the last call, in order."""
        events: list[int] = []
        if self.fd is None:
            return events
        while True:
            try:
                buf = os.read(self.fd, 4096)
            except OSError:  # BlockingIOError: nothing more
                return events
            if not buf:
                return events
            i = 0
            while i + _EVENT_HEADER.size <= len(buf):
                _wd, mask, _cookie, length = _EVENT_HEADER.unpack_from(buf, i)
                if mask & _IN_OPEN:
                    events.append(+1)
                if mask & (_IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE):
                    events.append(-1)
                i += _EVENT_HEADER.size + length

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


class PtyServer(LoopThread):
    """Serve ``device`` on a new pty pair; ``port`` is the slave path clients open.

    Use as a context manager or call :meth:`start` / :meth:`stop`; ``error`` holds what stopped its thread.
    """

    def __init__(self, device: SerialDevice, *, clock: Clock | None = None, name: str | None = None) -> None:
        self.device = device
        self.clock = clock if clock is not None else RealClock()
        if self.clock.is_virtual:
            raise ValueError("a pty server runs in real time: pass a RealClock (or no clock)")
        self.name = name or device.kind
        super().__init__(f"pty-{self.name}", log)
        self._master, slave = pty.openpty()
        tty.setraw(self._master)
        self.port = os.ttyname(slave)
        # Close our own slave handle so the master reads EIO while no client has the port open:
        # that is how the server sees a client open and close it (an Arduino resets on open).
        os.close(slave)
        os.set_blocking(self._master, False)
        self._watch = _OpenCloseWatch(self.port)
        self._handles = 0  # client handles open on the slave, as inotify counts them
        self.client_open = False
        self.opens = 0
        self._opened_at = 0.0
        self._rng = random.Random(0x5EED)

    # -- lifecycle (start, stop, the context manager: LoopThread) ------------------------------
    def _after_stop(self) -> None:
        try:
            os.close(self._master)
        except OSError:
            pass
        self._watch.close()

    # -- the loop -------------------------------------------------------------------------------
    def _client_baud(self) -> int | None:
        try:
            attrs = termios.tcgetattr(self._master)
        except termios.error:
            return None
        return _BAUD_BY_CONSTANT.get(attrs[5])  # ospeed: what the client configured

    def _on_thread_start(self) -> None:
        """Linux: this thread's timer slack 50 µs → 1 µs, so timed waits end on time."""
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1000, 0, 0, 0)
        except (OSError, AttributeError):  # not Linux: keep the default slack
            pass

    def _once(self) -> None:
        if self._watch.fd is not None:
            self._follow_handles()
            if self.client_open:
                self._serve_once()
            else:
                time.sleep(_CLOSED_POLL_S)
        elif not self.client_open:
            self._wait_for_open()
        else:
            self._serve_once()

    def _follow_handles(self) -> None:
        """With inotify: the device opens when the first client handle opens and closes when the
        last one closes, every time, however quickly a client closes and reopens (an Uno resets on
        each new DTR edge). A second handle opened and closed meanwhile changes nothing."""
        for step in self._watch.drain():
            before = self._handles
            self._handles = max(0, self._handles + step)
            if before == 0 and self._handles > 0:
                self._open_device()
            elif before > 0 and self._handles == 0:
                self._close_device()

    def _wait_for_open(self) -> None:
        """Without inotify: the master reads EIO while no client holds the slave."""
        data = read_master(self._master)
        if data is None:
            time.sleep(_CLOSED_POLL_S)
            return
        self._open_device()
        if data:
            self._feed(data, self.clock.now_s())

    def _open_device(self) -> None:
        now = self.clock.now_s()
        self.client_open = True
        self.opens += 1
        self._opened_at = now
        self.device.set_client_baud(None)  # the rate is checked per chunk, here (see the module docstring)
        self.device.open(now)
        log.debug("%s: client opened %s", self.name, self.port)

    def _close_device(self) -> None:
        self.client_open = False
        self.device.close(self.clock.now_s())
        log.debug("%s: client closed %s", self.name, self.port)

    def _serve_once(self) -> None:
        now = self.clock.now_s()
        nxt = self.device.next_ready_s()
        wait = _IDLE_POLL_S if nxt is None else min(_IDLE_POLL_S, max(0.0, nxt - now))
        timeout = wait - _SPIN_S if wait > _SPIN_S else 0.0
        readable, _, _ = select.select([self._master], [], [], timeout)
        if readable:
            data = read_master(self._master)
            if data is None:
                if self._watch.fd is None:
                    self._close_device()
                else:
                    time.sleep(_CLOSED_POLL_S)  # closed for now: inotify says when, and the next open
                return
            if data:
                self._feed(data, self.clock.now_s())
        if not self._settled(self.clock.now_s()):
            self.device.advance_to(self.clock.now_s())
            return
        out = self.device.pop_ready(self.clock.now_s())
        if out:
            self._write_all(self._on_wire(out, self.device.baud, self._client_baud()))

    def _settled(self, now: float) -> bool:
        """After an open, hold the output the device's ``open_hold_s``, then until the client's rate
        matches (or SETTLE_S)."""
        since = now - self._opened_at
        if since < float(getattr(self.device, "open_hold_s", 0.0)):
            return False
        return since >= SETTLE_S or self._client_baud() in (None, self.device.baud)

    def _feed(self, data: bytes, now: float) -> None:
        # Clients may change the baud rate at any time (the SDK's setBaudRate does): read it per chunk.
        data = self._on_wire(data, self._client_baud(), self.device.baud)
        if data:
            self.device.feed(data, now)

    def _on_wire(self, data: bytes, sender_baud: int | None, receiver_baud: int | None) -> bytes:
        """What a receiver at another rate samples: framing garbage, more or fewer bytes."""
        if sender_baud is None or receiver_baud is None or sender_baud == receiver_baud:
            return data
        n = int(round(len(data) * receiver_baud / sender_baud))
        return bytes(self._rng.randrange(256) for _ in range(n))

    def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)
                view = view[n:]
            except BlockingIOError:
                select.select([], [self._master], [], 0.01)
            except OSError as exc:
                if exc.errno == errno.EIO:  # the client went away mid-write: bytes are lost
                    return
                raise
