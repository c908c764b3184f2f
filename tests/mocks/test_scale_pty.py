"""``tactile-rig mock serve scale`` on a pty: a plain pyserial line reader, then the driver."""

from __future__ import annotations

import re

import pytest
import serial

from tactile_rig.drivers.scale import Scale, parse_line
from tactile_rig.testing.serve import serve_in_subprocess
from tactile_rig.testing.strategies_scale import crc8_reference


@pytest.mark.pty
def test_a_plain_pyserial_reader_and_the_driver_read_the_served_scale() -> None:
    with serve_in_subprocess("scale", "--rate", "80", "--param", "boot_s=0.1") as info:
        assert info["device"] == "scale" and info["rate_sps"] == 80 and info["boot_s"] == 0.1
        with serial.Serial(info["port"], 57600, timeout=1.0) as ser:
            lines = [ser.readline() for _ in range(12)]
        # The first line may carry the bootloader's glitch bytes; every later one is a whole line.
        assert re.search(rb"[BIS],[^*\r\n]*\*[0-9A-F]{2}$", lines[0].rstrip(b"\r\n"))
        assert all(l.endswith(b"\r\n") for l in lines)
        # Checked independently of the driver's parser: the sketch's frame layout and CRC-8 by long division.
        for l in lines[1:]:
            body, _, crc = l.rstrip(b"\r\n").rpartition(b"*")
            assert int(crc, 16) == crc8_reference(body), l
            tag, seq, grams, raw = body.split(b",")
            assert tag == b"S" and 0 <= int(seq) <= 65535 and float(grams) == float(grams), l
            assert -(2**23) <= int(raw) < 2**23, l
        kinds = [parse_line(l.rstrip(b"\r\n"), 0.0).kind for l in lines[1:]]
        assert kinds == ["sample"] * 11
        seqs = [parse_line(l.rstrip(b"\r\n"), 0.0).reading.seq for l in lines[1:]]
        assert seqs == list(range(seqs[0], seqs[0] + 11))
        # The driver: its DTR toggle is refused by the pty (ENOTTY) and must not crash it.
        with Scale(info["port"], boot_timeout_s=3.0) as scale:
            got = scale.read_many(20, timeout_s=1.0)
            # A quick reopen may slip past the pty server's open detection (no reset): then the
            # driver starts mid-stream and asks the sketch for its ID line.
            seqs = [r.seq for r in got]
            assert scale.info.rate_sps == 80 and seqs == list(range(seqs[0], seqs[0] + 20))
            assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0
