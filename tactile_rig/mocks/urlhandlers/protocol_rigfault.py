"""``rigfault://<inner-url>#faults`` — wrap any port and corrupt what the host receives.

Example: ``rigfault://rigsim://scale?rate=80#drop=0.001&flip=0.0005&seed=2``. The faults are
described in :mod:`tactile_rig.mocks.faults`; the injector is ``port.faults``.
"""

from __future__ import annotations

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from tactile_rig.mocks.faults import FaultInjector


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
        try:
            self.faults = FaultInjector.from_query(query, source=url)
        except ValueError as exc:
            raise SerialException(str(exc)) from exc
        self.inner = serial.serial_for_url(inner_url, baudrate=self._baudrate, timeout=self._timeout)
        self._pending = bytearray()
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
            self.inner.close()
        self.is_open = False

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        assert self.inner is not None and self.faults is not None
        n = self.inner.in_waiting
        if n:
            self._pending += self.faults.apply(self.inner.read(n))
        else:
            self.faults.check_connected()
        return len(self._pending)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        assert self.inner is not None and self.faults is not None
        self.faults.check_connected()
        if len(self._pending) < size:
            self.inner.timeout = self._timeout
            got = self.inner.read(size - len(self._pending))
            self._pending += self.faults.apply(got)
        data = bytes(self._pending[:size])
        del self._pending[:size]
        return data

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        assert self.inner is not None and self.faults is not None
        self.faults.check_connected()
        return self.inner.write(data)

    def reset_input_buffer(self) -> None:
        self._pending.clear()
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
