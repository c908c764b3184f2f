"""pytest fixtures for users' own tests: ``pytest_plugins = ["tactile_rig.testing.pytest_plugin"]``.

- ``rig_pty(device)``: serve a SerialDevice on a pty for the test; returns the slave path.
- ``rig_inprocess(device, clock=None)``: register it for ``rigsim://@...``; returns the URL.
"""

from __future__ import annotations

from contextlib import ExitStack
from typing import Callable, Iterator

import pytest

from tactile_rig.mocks.serial_device import SerialDevice
from tactile_rig.testing.serve import serve_in_process, serve_on_pty


@pytest.fixture
def rig_pty() -> Iterator[Callable[[SerialDevice], str]]:
    with ExitStack() as stack:

        def start(device: SerialDevice) -> str:
            return stack.enter_context(serve_on_pty(device)).port

        yield start


@pytest.fixture
def rig_inprocess() -> Iterator[Callable[..., str]]:
    with ExitStack() as stack:

        def start(device: SerialDevice, clock=None) -> str:
            return stack.enter_context(serve_in_process(device, clock))

        yield start
