"""A client that opens a pty slowly, as a terminal program or a careless script does: at the pty's
current line rate, setting its own (115200) a moment later. Used by the GRBL mock's banner test and
by ``benchmarks/bench_scale_jig.py``'s connect count."""

from __future__ import annotations

import os
import select
import termios
import time
import tty

GRBL_BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"


def read_banner(port: str, lag_s: float, timeout_s: float = 2.0) -> bytes:
    """Open ``port`` as a slow client does: at the pty's default rate, setting 115200 ``lag_s`` later;
    what it read until GRBL's banner ended (or ``timeout_s``)."""
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        time.sleep(lag_s)
        tty.setraw(fd)
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        got = b""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not got.endswith(b"help]\r\n"):
            if select.select([fd], [], [], 0.05)[0]:
                got += os.read(fd, 256)
    finally:
        os.close(fd)
    time.sleep(0.02)  # let the server see the close, so the next open is a new DTR reset
    return got
