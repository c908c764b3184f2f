"""``rigfault://<inner-url>#faults`` — wrap any port and corrupt what the host receives.

Example: ``rigfault://rigsim://scale?rate=80#drop=0.001&flip=0.0005&seed=2``. The faults are
described in :mod:`tactile_rig.mocks.faults`; the injector is ``port.faults``. Time-based faults
(``late``, ``stall``, ``unplug``) run on the inner port's clock (virtual for in-process mocks). An
unplug outlives the handle: the same URL cannot be opened again until the cable is "back", and
reopening it then opens (and so resets) the device again, as a USB-powered board does.
"""

from __future__ import annotations

import errno
import math
import threading
from collections import deque

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.mocks.faults import FaultInjector, reboot_device

# URL -> (absent until, on the inner clock; the injector), so an unplug outlives the handle that saw it
_AWAY: dict[str, tuple[float, FaultInjector]] = {}
_AWAY_LOCK = threading.Lock()


def _eio() -> OSError:
    return OSError(errno.EIO, "Input/output error (rigfault: device unplugged)")


class Serial(SerialBase):
    inner: SerialBase | None = None
    faults: FaultInjector | None = None

    def open(self) -> None:
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        url = self._port
        rest = url[len("rigfault://"):]
        inner_url, _, query = rest.partition("#")
        if not inner_url:
            raise SerialException(f"{url}: no inner port after rigfault://")
        with _AWAY_LOCK:
            away = _AWAY.get(url)
        try:
            # The injector carries on across a reopen of the same URL (same random stream, same counts).
            self.faults = away[1] if away is not None else FaultInjector.from_query(query, source=url)
        except ValueError as exc:
            raise SerialException(str(exc)) from exc
        inner = serial.serial_for_url(inner_url, baudrate=self._baudrate, timeout=self._timeout)
        clock: Clock = getattr(inner, "clock", None) or RealClock()
        if away is not None:
            if clock.now_s() < away[0]:
                inner.close()
                raise SerialException(errno.ENOENT, f"could not open port {url}: [Errno 2] No such file or "
                                                    "directory (rigfault: unplugged)")
            with _AWAY_LOCK:
                _AWAY.pop(url, None)
        self.inner = inner
        self._clock = clock
        self._pending = bytearray()  # deliverable now
        self._held: deque[tuple[float, bytes, bool]] = deque()  # (release time, bytes, ends a read)
        self._dead = False
        self.is_open = True

    def from_url(self, url: str) -> str:
        return url

    @property
    def clock(self):  # the inner port's clock, so deadlines stay virtual for in-process mocks
        return getattr(self.inner, "clock", None)

    def _reconfigure_port(self) -> None:
        if self.inner is not None:
            self.inner.baudrate = self._baudrate
            self.inner.timeout = self._timeout

    def close(self) -> None:
        if self.inner is not None:
            try:
                self.inner.close()
            except (SerialException, OSError):
                pass
        self.is_open = False

    # -- faults ---------------------------------------------------------------------------------
    def _check(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        assert self.faults is not None
        if self._dead:
            raise _eio()
        self.faults.check_connected()

    def _arrive(self, data: bytes) -> None:
        assert self.faults is not None
        fate = self.faults.chunk(data, self._clock.now_s())
        if fate.reboot:
            reboot_device(getattr(self.inner, "device", None), self._clock.now_s())
        if fate.unplug_s is not None:
            self._dead = True
            with _AWAY_LOCK:
                _AWAY[self._port] = (self._clock.now_s() + fate.unplug_s, self.faults)
            raise _eio()
        if not fate.data:
            return
        if fate.split_at is not None:
            self._held.append((fate.release_s, fate.data[:fate.split_at], True))
            self._held.append((fate.release_s, fate.data[fate.split_at:], False))
        else:
            self._held.append((fate.release_s, fate.data, False))

    def _release(self) -> bool:
        """Move what is due into the deliverable bytes; True if a split ends this read."""
        now = self._clock.now_s()
        while self._held and self._held[0][0] <= now:
            _, data, ends = self._held.popleft()
            self._pending += data
            if ends:
                return True
        return False

    def _fetch(self, wait_s: float) -> None:
        assert self.inner is not None
        self.inner.timeout = max(0.0, wait_s)
        got = self.inner.read(1)
        if got:
            n = self.inner.in_waiting
            if n:
                self.inner.timeout = 0
                got += self.inner.read(n)
            self._arrive(got)

    @property
    def in_waiting(self) -> int:
        self._check()
        assert self.inner is not None
        if self.inner.in_waiting:
            self._fetch(0.0)
        self._release()
        return len(self._pending)

    def read(self, size: int = 1) -> bytes:
        self._check()
        timeout = self._timeout
        t0 = self._clock.now_s()
        limit = math.inf if timeout is None else t0 + timeout
        while len(self._pending) < size:
            if self.faults is not None and self.faults.disconnected:
                break  # what arrived before the unplug is delivered; the next call fails
            if self._release():
                break
            if len(self._pending) >= size:
                break
            now = self._clock.now_s()
            wait = limit - now
            if self._held:
                wait = min(wait, self._held[0][0] - now)
            if timeout == 0:
                self._fetch(0.0)
                self._release()
                break
            if now >= limit:
                break
            self._fetch(min(wait, 3600.0))
            if self._clock.now_s() >= limit and not self._held:
                self._release()
                break
        data = bytes(self._pending[:size])
        del self._pending[:size]
        return data

    def write(self, data: bytes) -> int:
        self._check()
        assert self.inner is not None
        return self.inner.write(data)

    def reset_input_buffer(self) -> None:
        self._check()
        self._pending.clear()
        self._held.clear()
        if self.inner is not None:
            self.inner.reset_input_buffer()

    def reset_output_buffer(self) -> None:
        if self.inner is not None:
            self.inner.reset_output_buffer()

    def _update_dtr_state(self) -> None:
        if self.inner is not None:
            self.inner.dtr = self._dtr_state

    def _update_rts_state(self) -> None:
        if self.inner is not None:
            self.inner.rts = self._rts_state

    def _update_break_state(self) -> None:
        pass
