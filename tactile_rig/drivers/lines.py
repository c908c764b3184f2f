"""The line pump of line-oriented devices (the scale's sketch, GRBL): bytes off the port into lines, with deadlines.

:class:`LineSplitter` is pure: bytes in, in any split, complete lines out (without the ``\\n``),
an over-long run without a newline cut to its tail. :class:`LineDriver` is the template the scale
and the jig drivers are written on: :meth:`LineDriver._pump` waits for the first bytes (at most
``wait_s``), takes whatever else is already waiting, and hands the bytes to the driver's codec
(``_take_bytes``, the one primitive); :meth:`LineDriver._pump_until` pumps until a condition holds
or a deadline passes. Reconnect-with-backoff and the counters come from
:class:`~tactile_rig.drivers.base.PortDriver`.
"""

from __future__ import annotations

from typing import Callable

from tactile_rig.core.clock import Deadline
from tactile_rig.core.errors import NotConnected
from tactile_rig.drivers.base import PortDriver
from tactile_rig.drivers.transport import SerialTransport


class LineSplitter:
    """Bytes in (any split), lines out. ``max_line``: keep at most that many bytes of a line that
    has not ended (a stream of garbage with no newline), counting each cut in ``overlong``."""

    def __init__(self, *, max_line: int | None = None) -> None:
        self._buf = bytearray()
        self.max_line = max_line
        self.overlong = 0

    def push(self, data: bytes) -> None:
        """Append bytes read from the port."""
        self._buf += data

    def pop(self) -> bytes | None:
        """The next complete line (without its ``\\n``), or None until one has ended."""
        idx = self._buf.find(b"\n")
        if idx < 0:
            if self.max_line is not None and len(self._buf) > self.max_line:
                self.overlong += 1
                del self._buf[: -self.max_line]
            return None
        line = bytes(self._buf[:idx])
        del self._buf[: idx + 1]
        return line

    def feed(self, data: bytes) -> list[bytes]:
        """:meth:`push` then every complete line."""
        self.push(data)
        out = []
        while (line := self.pop()) is not None:
            out.append(line)
        return out

    def clear(self) -> None:
        """Forget a partial line (the port was reopened)."""
        self._buf.clear()

    @property
    def pending(self) -> bytes:
        """The start of a line that has not ended yet."""
        return bytes(self._buf)


class LineDriver(PortDriver):
    """A :class:`PortDriver` whose device prints lines on a :class:`SerialTransport`.

    The subclass implements ``_take_bytes(data, t_s)``: decode the bytes (with its own
    :class:`LineSplitter` or codec), act on each complete line, return how many it took.
    """

    transport: SerialTransport | None

    def _take_bytes(self, data: bytes, t_s: float) -> int:
        raise NotImplementedError(f"{type(self).__name__} does not implement _take_bytes()")

    def _pump(self, wait_s: float) -> int:
        """Read what arrives within ``wait_s`` (returning at the first bytes, with whatever else is
        already waiting); hand it to the codec stamped with the port's time; return the lines taken."""
        transport = self.transport
        if transport is None:
            raise NotConnected(f"the port of {self.device} is not open", device=self.device)
        data = transport.read_some(1, wait_s)
        if data:
            data += transport.read_available()
        if not data:
            return 0
        return self._take_bytes(data, transport.clock.now_s())

    def _pump_until(self, done: Callable[[], bool], deadline: Deadline, timeout: Callable[[], Exception], *,
                    check: Callable[[], None] | None = None) -> None:
        """Pump until ``done()``; before each wait ``check()`` may raise, and a passed ``deadline``
        raises ``timeout()``."""
        while not done():
            if check is not None:
                check()
            if deadline.expired():
                raise timeout()
            self._pump(deadline.remaining_s() or 0.0)
