"""A USB cable a test can pull: while unplugged, an open port raises EIO and its path cannot be opened.

``Plug(monkeypatch)`` wraps :func:`tactile_rig.drivers.transport.open_serial`, which every driver
opens its port through (the scale's and the jig's :class:`SerialTransport`, the Dynamixel bus's
``UrlPortHandler``), so one plug serves every kind of driver.
"""

from __future__ import annotations

import errno
from typing import Any

import pytest

import tactile_rig.drivers.transport as transport
from tactile_rig.core.errors import NotConnected


class Plug:
    """Pulls the USB cable: while unplugged, the open port raises EIO and the path cannot be opened."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.plugged = True
        self.opens = 0
        real = transport.open_serial

        def open_serial(port: str, **kw: Any) -> Any:
            self.opens += 1
            if not self.plugged:
                raise NotConnected(f"cannot open port {port!r}: [Errno 2] No such file or directory",
                                   device=kw.get("device"))
            return _Pluggable(real(port, **kw), self)

        monkeypatch.setattr(transport, "open_serial", open_serial)


class _Pluggable:
    def __init__(self, inner: Any, plug: Plug) -> None:
        self.__dict__.update(inner=inner, plug=plug)

    def _check(self) -> None:
        if not self.plug.plugged:
            raise OSError(errno.EIO, "Input/output error")

    @property
    def in_waiting(self) -> int:
        self._check()
        return self.inner.in_waiting

    def read(self, n: int = 1) -> bytes:
        self._check()
        return self.inner.read(n)

    def write(self, data: bytes) -> int:
        self._check()
        return self.inner.write(data)

    def reset_input_buffer(self) -> None:
        self._check()
        self.inner.reset_input_buffer()

    def close(self) -> None:
        self.inner.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.inner, name, value)
