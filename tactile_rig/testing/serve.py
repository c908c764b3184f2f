"""Start a mock device on a pty (real time) or in process (virtual time) for a test or a script."""

from __future__ import annotations

import itertools
from contextlib import contextmanager
from typing import Iterator

from tactile_rig.core.clock import Clock, VirtualClock
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.mocks.registry import register_instance, unregister_instance
from tactile_rig.mocks.serial_device import SerialDevice

_counter = itertools.count()


@contextmanager
def serve_on_pty(device: SerialDevice) -> Iterator[PtyServer]:
    """Serve ``device`` on a new pty pair in real time; yields the server (``.port`` is the path)."""
    server = PtyServer(device).start()
    try:
        yield server
    finally:
        server.stop()
        if server.error is not None:
            raise RuntimeError(f"the pty server of {device.kind} failed: {server.error!r}") from server.error


@contextmanager
def serve_in_process(device: SerialDevice, clock: Clock | None = None, *, name: str | None = None) -> Iterator[str]:
    """Register ``device`` for ``rigsim://@name`` on ``clock`` (a new VirtualClock by default); yield the URL."""
    name = name or f"{device.kind}-{next(_counter)}"
    url = register_instance(name, device, clock if clock is not None else VirtualClock())
    try:
        yield url
    finally:
        unregister_instance(name)
