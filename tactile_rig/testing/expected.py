"""``expected_protocol``: assert the exact bytes a driver exchanges with its device."""

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
    """

    kind = "expected"

    def __init__(self, exchanges: Sequence[tuple[bytes | None, bytes | None]], *, baud: int = 115200) -> None:
        super().__init__(baud=baud, timing=False)
        self.exchanges = [(None if h is None else bytes(h), bytes(d or b"")) for h, d in exchanges]
        self.index = 0
        self._partial = bytearray()

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
        if self.index < len(self.exchanges) or self._partial:
            left = self.exchanges[self.index:]
            raise AssertionError(
                f"{len(left)} expected exchange(s) were not used; next expected host bytes: "
                f"{left[0][0].hex(' ') if left and left[0][0] else '(none)'}; "
                f"partial: {bytes(self._partial).hex(' ')}"
            )


@contextmanager
def expected_protocol(
    exchanges: Sequence[tuple[bytes | None, bytes | None]], *, baud: int = 115200
) -> Iterator[str]:
    """Yield a ``rigsim://@...`` URL whose device accepts exactly ``exchanges``, in order.

    Example::

        with expected_protocol([(b"t\\n", b"T,ok\\r\\n")]) as port:
            Scale(port).tare()

    On exit every exchange must have been used, else ``AssertionError``.
    """
    device = ExpectedProtocolDevice(exchanges, baud=baud)
    name = f"expected-{next(_counter)}"
    url = register_instance(name, device, VirtualClock())
    try:
        yield url
        device.assert_all_used()
    finally:
        unregister_instance(name)
