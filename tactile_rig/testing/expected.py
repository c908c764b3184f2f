"""``expected_protocol``: assert the exact bytes a driver exchanges with its device.

Every expected exchange must be used, every byte the host sends must be the expected one, and every
byte the device answers must be read by the driver: a reply left unread (or flushed away) is as much
a driver bug as a wrong request.
"""

from __future__ import annotations

import itertools
from contextlib import contextmanager
from typing import Iterator, Sequence

from tactile_rig.core.clock import VirtualClock
from tactile_rig.mocks.registry import register_instance, unregister_instance
from tactile_rig.mocks.serial_device import SerialDevice

_counter = itertools.count()


class ExpectedProtocolDevice(SerialDevice):
    """A device that accepts exactly a script of ``(host_bytes, device_bytes)`` exchanges.

    ``host_bytes`` may arrive over several writes; once it is complete the device answers
    ``device_bytes`` (``None`` or ``b""``: no answer). ``host_bytes=None`` means the device sends
    ``device_bytes`` unprompted when the port opens (a boot banner). Any byte that differs raises
    ``AssertionError`` in the driver's ``write`` call, naming the exchange and both byte strings.
    :meth:`assert_all_used` also fails when the driver left answered bytes unread.
    """

    kind = "expected"

    def __init__(self, exchanges: Sequence[tuple[bytes | None, bytes | None]], *, baud: int = 115200) -> None:
        super().__init__(baud=baud, timing=False)
        self.exchanges = [(None if h is None else bytes(h), bytes(d or b"")) for h, d in exchanges]
        self.index = 0
        self._partial = bytearray()
        self.bytes_sent = 0  # answered to the host
        self.bytes_read = 0  # read by the host

    def emit(self, data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
        self.bytes_sent += len(data)
        return super().emit(data, t_s, delay_s=delay_s, reply=reply)

    def host_read(self, n_bytes: int) -> None:
        self.bytes_read += n_bytes

    def on_open(self, t_s: float) -> None:
        while self.index < len(self.exchanges) and self.exchanges[self.index][0] is None:
            self.emit(self.exchanges[self.index][1], t_s, reply=False)
            self.index += 1

    def on_bytes(self, data: bytes, t_s: float) -> None:
        for b in data:
            if self.index >= len(self.exchanges):
                raise AssertionError(
                    f"unexpected byte {b:02x} after all {len(self.exchanges)} exchanges were used "
                    f"(received so far in this write: {bytes(self._partial + bytes([b])).hex(' ')})"
                )
            expected_host, reply = self.exchanges[self.index]
            assert expected_host is not None
            self._partial.append(b)
            if not expected_host.startswith(self._partial):
                raise AssertionError(
                    f"exchange {self.index}: expected host bytes {expected_host.hex(' ')}, "
                    f"got {bytes(self._partial).hex(' ')}"
                )
            if len(self._partial) == len(expected_host):
                self._partial.clear()
                self.index += 1
                if reply:
                    self.emit(reply, t_s)
                self.on_open(t_s)  # unprompted output scheduled right after this exchange

    def assert_all_used(self) -> None:
        """Every exchange used and every answered byte read by the host, else ``AssertionError``."""
        if self.index < len(self.exchanges) or self._partial:
            left = self.exchanges[self.index:]
            raise AssertionError(
                f"{len(left)} expected exchange(s) were not used; next expected host bytes: "
                f"{left[0][0].hex(' ') if left and left[0][0] else '(none)'}"
                + (f"; received part of it: {bytes(self._partial).hex(' ')}" if self._partial else "")
            )
        if self.bytes_read < self.bytes_sent:
            raise AssertionError(
                f"the driver left {self.bytes_sent - self.bytes_read} of the {self.bytes_sent} answered "
                f"byte(s) unread (read or flushed unseen): a reply it never looked at"
            )


@contextmanager
def expected_protocol(
    exchanges: Sequence[tuple[bytes | None, bytes | None]], *, baud: int = 115200
) -> Iterator[str]:
    """Yield a ``rigsim://@...`` URL whose device accepts exactly ``exchanges``, in order.

    A Protocol 2.0 ping of servo 1 through the real dynamixel-sdk, with the e-manual's packet; the
    MX-64(2.0) answers model 311 (0x0137), firmware 45:

    >>> from tactile_rig.drivers.dynamixel import DynamixelBus
    >>> ping = bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e")
    >>> status = bytes.fromhex("ff ff fd 00 01 07 00 55 00 37 01 2d 8b 40")
    >>> with expected_protocol([(ping, status)], baud=1_000_000) as port:
    ...     with DynamixelBus(port, baudrate=1_000_000) as bus:
    ...         bus.ping(1)
    311

    A request the script does not expect fails in the driver's write; on exit every exchange must
    have been used and every answered byte read, else ``AssertionError``:

    >>> with expected_protocol([(ping, status)], baud=1_000_000) as port:
    ...     with DynamixelBus(port, baudrate=1_000_000) as bus:
    ...         pass
    Traceback (most recent call last):
    AssertionError: 1 expected exchange(s) were not used; next expected host bytes: ff ff fd 00 01 03 00 01 19 4e
    """
    device = ExpectedProtocolDevice(exchanges, baud=baud)
    name = f"expected-{next(_counter)}"
    url = register_instance(name, device, VirtualClock())
    try:
        yield url
        device.assert_all_used()
    finally:
        unregister_instance(name)
