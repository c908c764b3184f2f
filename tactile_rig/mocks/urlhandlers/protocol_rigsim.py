"""``rigsim://`` — a mock device in the same process, no threads, on the device's clock.

``serial.serial_for_url("rigsim://dynamixel?ids=1,2&protocol=2")`` or ``"rigsim://@name"`` (see
:mod:`tactile_rig.mocks.registry`). On a :class:`~tactile_rig.core.clock.VirtualClock` a read that must
wait advances virtual time to when the device's bytes arrive (or to the read's timeout), so a
driver sees exactly the timing it would see on a wire, instantly. A read with ``timeout=0`` (the
busy polling of dynamixel-sdk) may advance time only to deliver a reply already in flight, never
to wait for unsolicited output.
"""

from __future__ import annotations

import math

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from tactile_rig.core.clock import Clock
from tactile_rig.mocks.registry import device_from_url
from tactile_rig.mocks.serial_device import SerialDevice


class Serial(SerialBase):
    """A pyserial port backed by an in-process :class:`SerialDevice`."""

    device: SerialDevice | None = None
    is_open: bool = False
    clock: Clock | None = None

    def open(self) -> None:
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        if self.is_open:
            raise SerialException("port already open")
        try:
            self.device, self.clock = device_from_url(self._port)
        except ValueError as exc:
            raise SerialException(str(exc)) from exc
        self._rx = bytearray()
        self.is_open = True
        self._reconfigure_port()
        self.device.open(self.clock.now_s())
        self._dtr_state = True

    def from_url(self, url: str) -> str:
        return url

    def _reconfigure_port(self) -> None:
        if self.device is not None:
            self.device.set_client_baud(self._baudrate)

    def close(self) -> None:
        if self.is_open and self.device is not None and self.clock is not None:
            self.device.close(self.clock.now_s())
        self.is_open = False

    # -- data --------------------------------------------------------------------------------
    def _collect(self) -> None:
        assert self.device is not None and self.clock is not None
        self._rx += self.device.pop_ready(self.clock.now_s())

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        self._collect()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        assert self.device is not None and self.clock is not None
        timeout = self._timeout
        t0 = self.clock.now_s()
        limit = math.inf if timeout is None else t0 + timeout
        while True:
            self._collect()
            if len(self._rx) >= size:
                break
            now = self.clock.now_s()
            if self.clock.is_virtual:
                if timeout == 0:
                    nxt = self.device.next_ready_s(replies_only=True)
                    if nxt is None:
                        break
                    self.clock.advance_to(nxt)  # type: ignore[attr-defined]
                    continue
                nxt = self.device.next_ready_s()
                if nxt is None and limit == math.inf:
                    raise SerialException(
                        f"{self._port}: read of {size} byte(s) with no timeout would block forever: "
                        "the mock has nothing scheduled to send"
                    )
                target = limit if nxt is None else min(nxt, limit)
                if target <= now and now >= limit:
                    break
                self.clock.advance_to(target)  # type: ignore[attr-defined]
                if self.clock.now_s() >= limit:
                    self._collect()
                    break
            else:
                if timeout == 0 or now >= limit:
                    break
                nxt = self.device.next_ready_s()
                target = min(limit, nxt if nxt is not None else now + 0.001)
                self.clock.sleep(max(0.0, min(target - now, 0.01)))
        data = bytes(self._rx[:size])
        del self._rx[:size]
        if data:
            self.device.host_read(len(data))
        return data

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        assert self.device is not None and self.clock is not None
        data = bytes(data)
        self.device.feed(data, self.clock.now_s())
        return len(data)

    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self._collect()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    def flush(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    # -- modem lines: an Arduino resets on a DTR edge -------------------------------------------
    def _update_dtr_state(self) -> None:
        hook = getattr(self.device, "on_dtr", None)
        if hook is not None and self.clock is not None:
            hook(bool(self._dtr_state), self.clock.now_s())

    def _update_rts_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
