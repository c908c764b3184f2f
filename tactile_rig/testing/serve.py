"""Start a mock device on a pty (real time), in another process on a pty, or in process (virtual
time), for a test or a script."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from contextlib import contextmanager
from typing import Any, Iterator

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


@contextmanager
def serve_in_subprocess(kind: str, *options: str, stop_timeout_s: float = 5.0) -> Iterator[dict[str, Any]]:
    """Run ``tactile-rig mock serve KIND OPTIONS...`` in another process, as a device is on the other
    side of a USB cable, and yield the JSON line it prints (``port`` is the pty path to open). On
    leaving, the server gets SIGTERM, then SIGKILL after ``stop_timeout_s``. A server that prints
    nothing (a bad option: it exits 2 with one line on stderr) is a ``RuntimeError`` with its exit code."""
    proc = subprocess.Popen([sys.executable, "-m", "tactile_rig.cli", "mock", "serve", kind, *options],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    try:
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(f"tactile-rig mock serve {kind} printed nothing (exit {proc.wait(stop_timeout_s)})")
        yield json.loads(line)
    finally:
        proc.terminate()
        try:
            proc.wait(stop_timeout_s)
        except subprocess.TimeoutExpired:  # a wedged server
            proc.kill()
            proc.wait(stop_timeout_s)
        proc.stdout.close()
