"""``tactile-rig mock serve scale --firmware``: the compiled sketch on the simulated board, on a pty."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import serial

from tactile_rig.cli import main
from tactile_rig.drivers.scale import parse_line
from tactile_rig.mocks import scale_firmware as sf
from tactile_rig.testing.strategies_scale import crc8_reference
from tests._firmware import firmware_build


@pytest.fixture(scope="module")
def firmware():
    """The compiled sketch and board (skip, or fail under TACTILE_RIG_REQUIRE_FIRMWARE=1, without them)."""
    return firmware_build()


@pytest.mark.pty
@pytest.mark.slow
def test_serve_prints_the_port_and_the_control_fifo_moves_the_load(firmware) -> None:
    cmd = [sys.executable, "-m", "tactile_rig.cli", "mock", "serve", "scale", "--firmware", "--rate", "80",
           "--param", "noise_counts=0", "--param", "drift_counts=0", "--param", "spike_prob=0",
           "--param", "boot_junk=0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        info = json.loads(proc.stdout.readline())
        assert info["device"] == "scale" and info["rate_sps"] == 80 and info["firmware"] == "arduino_scale"
        assert info["port"].startswith("/dev/pts/") and os.path.exists(info["control"])
        with serial.Serial(info["port"], 57600, timeout=4.0) as ser:
            lines = [ser.readline() for _ in range(5)]
            # Checked independently of the driver: the frame layout and the CRC-8 by long division.
            for line in lines:
                body, _, crc = line.rstrip(b"\r\n").rpartition(b"*")
                assert line.endswith(b"\r\n") and int(crc, 16) == crc8_reference(body), line
            assert lines[0].startswith(b"B,hx711-scale,1.1.0,80,696.000*")
            assert [line.split(b",")[:2] for line in lines[1:]] == [[b"S", b"%d" % i] for i in range(4)]
            with open(info["control"], "w") as control:
                control.write(f"force_n {0.1 * 9.80665!r}\n")  # 100 g
            time.sleep(0.4)  # the smoothing window (18 conversions) refills
            ser.reset_input_buffer()
            ser.readline()
            latest = parse_line(ser.readline().rstrip(b"\r\n"), 0.0).reading
        assert latest.grams == 100.0 and latest.raw == 84_000 + 69_600
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        proc.stdout.close()


@pytest.mark.parametrize(("argv", "message"), [
    (["mock", "serve", "jig", "--firmware"], "has no firmware here"),
    (["mock", "serve", "scale", "--firmware", "--param", "speed=3"], "unknown parameter 'speed'"),
    (["mock", "serve", "scale", "--firmware", "--scene", "press"], "control FIFO"),
    (["mock", "serve", "scale", "--firmware", "--param", "force_n=heavy"], "is not a number"),
    (["mock", "serve", "scale", "--firmware", "--baud", "9600"], "57600"),
])
def test_bad_firmware_options_are_one_line_and_exit_2(argv, message, capsys) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_a_rate_the_hx711_cannot_run_is_a_usage_error(capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(["mock", "serve", "scale", "--firmware", "--rate", "40"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "'10', '80'" in err and len(err.strip().splitlines()) == 1


def test_a_missing_toolchain_is_one_line_naming_the_packages(monkeypatch, capsys) -> None:
    monkeypatch.setattr(sf.toolchain, "missing_toolchain", lambda: ["avr-gcc", "libsimavr headers (/usr/include/simavr)"])
    assert main(["mock", "serve", "scale", "--firmware"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "avr-gcc" in err and sf.INSTALL_HINT in err
