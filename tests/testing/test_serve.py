"""serve_in_subprocess: a mock in another process, as ``tactile-rig mock serve`` runs it, gone on leaving."""

from __future__ import annotations

from pathlib import Path

import pytest
import serial

from tactile_rig.testing import serve_in_subprocess
from tactile_rig.testing.strategies_scale import crc8_reference


def _children() -> set[int]:
    """This process's child processes (Linux: /proc/self/task/*/children)."""
    return {int(pid) for f in Path("/proc/self/task").glob("*/children") for pid in f.read_text().split()}


@pytest.mark.pty
def test_the_served_mock_answers_on_the_port_it_printed_and_stops_on_leaving() -> None:
    before = _children()
    with serve_in_subprocess("scale", "--rate", "80", "--param", "boot_s=0.1") as info:
        server = _children() - before
        assert len(server) == 1 and info["device"] == "scale" and info["rate_sps"] == 80
        port = info["port"]
        with serial.Serial(port, 57600, timeout=2.0) as ser:
            ser.readline()  # the banner, perhaps behind the bootloader's glitch bytes
            line = ser.readline()
        body, _, crc = line.rstrip(b"\r\n").rpartition(b"*")
        assert body.startswith(b"S,") and int(crc, 16) == crc8_reference(body)
    assert not server & _children()  # the server stopped and was waited for


def test_a_server_that_refuses_its_options_is_an_error_naming_its_exit_code() -> None:
    with pytest.raises(RuntimeError, match=r"mock serve scale printed nothing \(exit 2\)"):
        with serve_in_subprocess("scale", "--rate", "40"):
            pass
