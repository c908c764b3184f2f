"""Base class of every serial mock: a firmware emulation that takes bytes and returns bytes.

A :class:`SerialDevice` knows nothing about threads or ptys. The host side calls
:meth:`SerialDevice.feed` with the bytes it wrote and the time it wrote them, and collects output
with :meth:`SerialDevice.pop_ready`. The device schedules its output with :meth:`emit`, which
applies the wire time of every byte at the device's baud rate (10 bits per byte: start, 8 data,
stop) after an optional processing delay, one byte after another on a half-duplex line, exactly
as the host would see it. Set ``timing=False`` to make replies instantaneous.

The same class is served two ways (see :mod:`tactile_rig.mocks.pty_server` and the ``rigsim://``
URL handler): on a pty pair in real time, and in process on a :class:`~tactile_rig.core.clock.VirtualClock`.
"""

from __future__ import annotations

import logging
import threading
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass

import numpy as np

log = logging.getLogger("tactile_rig.mocks")

BITS_PER_BYTE = 10  # 8N1: start bit + 8 data bits + stop bit


@dataclass
class _Chunk:
    ready_s: float  # time at which the last byte of the chunk has reached the host
    data: bytes
    reply: bool  # an answer to a host request (vs. unsolicited output such as a stream)


class SerialDevice(ABC):
    """Firmware emulation: bytes in at a time, bytes out at a time.

    Subclasses implement :meth:`on_bytes` (host bytes arriving at the device) and may override
    :meth:`on_open`, :meth:`on_close`, :meth:`on_tick` (integrate state, emit periodic output) and
    :meth:`next_event_s` (when ``on_tick`` will next emit, so a virtual clock can jump there).
    """

    #: name used in logs and in ``tactile-rig mock serve`` output
    kind: str = "device"

    def __init__(self, *, baud: int, timing: bool = True, seed: int = 0) -> None:
        if baud <= 0:
            raise ValueError(f"baud={baud!r} must be a positive number of bits per second")
        self.baud = int(baud)
        self.timing = bool(timing)
        self.client_baud: int | None = None  # None: unknown (assume it matches)
        self.is_open = False
        self._out: deque[_Chunk] = deque()
        self._tx_free_s = 0.0  # when the device's TX line is free again
        self._rx_free_s = 0.0  # when the host→device line is free again
        self._t_s = 0.0
        self._lock = threading.RLock()
        self._garble_rng = np.random.default_rng(seed + 7919)

    # -- to implement ----------------------------------------------------------------------
    @abstractmethod
    def on_bytes(self, data: bytes, t_s: float) -> None:
        """Bytes from the host have fully arrived at the device at time ``t_s``."""

    def on_open(self, t_s: float) -> None:
        """The host opened the port at ``t_s`` (an Arduino resets here)."""

    def on_close(self, t_s: float) -> None:
        """The host closed the port at ``t_s``."""

    def on_tick(self, t_s: float) -> None:
        """Integrate internal state up to ``t_s`` and emit periodic output that is due."""

    def next_event_s(self) -> float | None:
        """Time of the next unsolicited output ``on_tick`` will produce, or None."""
        return None

    # -- helpers for subclasses ----------------------------------------------------------
    def byte_time_s(self) -> float:
        """Seconds on the wire per byte at the device's baud (10 bits per byte)."""
        return BITS_PER_BYTE / self.baud

    def emit(self, data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
        """Send ``data`` starting ``delay_s`` after ``t_s``; return when its last byte reaches the host."""
        if not data:
            return t_s
        with self._lock:
            if self.timing:
                start = max(t_s + delay_s, self._tx_free_s)
                ready = start + len(data) * self.byte_time_s()
                self._tx_free_s = ready
            else:
                ready = t_s
            if self.client_baud is not None and self.client_baud != self.baud:
                data = self._garble(data, self.baud, self.client_baud)
            if data:
                self._out.append(_Chunk(ready, bytes(data), reply))
            return ready

    # -- host-facing API (used by the servers) -------------------------------------------------
    def open(self, t_s: float) -> None:
        with self._lock:
            self.advance_to(t_s)
            self.is_open = True
            self._out.clear()
            self._tx_free_s = self._rx_free_s = t_s
            self.on_open(t_s)

    def close(self, t_s: float) -> None:
        with self._lock:
            self.advance_to(t_s)
            self.is_open = False
            self._out.clear()  # bytes in flight to a closed port are lost
            self.on_close(t_s)

    def set_client_baud(self, baud: int | None) -> None:
        """Tell the device the host's baud rate; a mismatch garbles both directions."""
        with self._lock:
            self.client_baud = None if baud is None else int(baud)

    def feed(self, data: bytes, t_s: float) -> None:
        """The host wrote ``data`` at ``t_s``; it reaches the device after its wire time."""
        if not data:
            return
        with self._lock:
            if self.timing:
                # The host's UART clocks bytes out at its own rate.
                rate = self.client_baud or self.baud
                start = max(t_s, self._rx_free_s)
                t_rx = start + len(data) * BITS_PER_BYTE / rate
                self._rx_free_s = t_rx
            else:
                t_rx = t_s
            self.advance_to(t_rx)
            if self.client_baud is not None and self.client_baud != self.baud:
                data = self._garble(data, self.client_baud, self.baud)
                if not data:
                    return
            self.on_bytes(bytes(data), t_rx)

    def advance_to(self, t_s: float) -> None:
        """Integrate the device up to ``t_s`` (never backwards)."""
        with self._lock:
            if t_s > self._t_s:
                self._t_s = t_s
            self.on_tick(self._t_s)

    def pop_ready(self, t_s: float) -> bytes:
        """Bytes whose last bit has reached the host by ``t_s`` (whole emitted chunks)."""
        with self._lock:
            self.advance_to(t_s)
            out = bytearray()
            while self._out and self._out[0].ready_s <= t_s:
                out += self._out.popleft().data
            return bytes(out)

    def next_ready_s(self, *, replies_only: bool = False) -> float | None:
        """When the next output chunk is ready (or the next periodic event), or None."""
        with self._lock:
            candidates = [c.ready_s for c in self._out if c.reply or not replies_only]
            t_out = min(candidates) if candidates else None
            if replies_only:
                return t_out
            ev = self.next_event_s()
            if ev is None:
                return t_out
            return ev if t_out is None else min(t_out, ev)

    def host_read(self, n_bytes: int) -> None:
        """The in-process host read ``n_bytes`` of this device's output (a hook for test devices that
        check every reply is consumed; devices ignore it)."""

    def pending_output(self) -> int:
        """Number of bytes scheduled but not yet delivered."""
        with self._lock:
            return sum(len(c.data) for c in self._out)

    def _garble(self, data: bytes, sender_baud: int, receiver_baud: int) -> bytes:
        # A receiver at the wrong rate samples the line at its own rate: a slower receiver sees
        # fewer (merged) bytes, a faster one more; all of them framing garbage.
        n = int(round(len(data) * receiver_baud / sender_baud))
        return bytes(self._garble_rng.integers(0, 256, size=n, dtype=np.uint8))
