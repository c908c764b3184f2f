"""The compiled sketch on a simulated Uno served on a pty, in its own process and in real time."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from tactile_rig.core.errors import NotConnected
from tactile_rig.devices import scale as sp
from tactile_rig.mocks.scale_firmware.config import BoardConfig
from tactile_rig.mocks.scale_firmware.toolchain import FirmwareBuild, build

__all__ = ["SimulatedScaleBoard"]


class SimulatedScaleBoard:
    """The compiled sketch on a simulated Uno served on a pty (its own process, real time).

    ``port`` is the pty slave path any client opens (opening it resets the board, as DTR does on an
    Uno). ``eeprom_path`` keeps the EEPROM (the calibration) across runs; a temporary one otherwise.
    """

    def __init__(self, config: BoardConfig | None = None, *, eeprom_path: str | os.PathLike[str] | None = None,
                 start_timeout_s: float = 30.0) -> None:
        self.config = config or BoardConfig()
        self._tmp = tempfile.TemporaryDirectory(prefix="scale-board-")
        self.eeprom_path = Path(eeprom_path) if eeprom_path is not None else Path(self._tmp.name, "eeprom.bin")
        self.control_path = Path(self._tmp.name, "control")
        self.start_timeout_s = float(start_timeout_s)
        self.port: str | None = None
        self.build: FirmwareBuild | None = None
        self.proc: subprocess.Popen[str] | None = None
        self._control: int | None = None
        self._log: Any = None
        self._stats_n = 0

    def start(self) -> "SimulatedScaleBoard":
        if self.proc is not None:
            return self
        try:
            return self._start()
        except BaseException:
            self.stop()  # no process, FIFO or temporary folder left behind
            raise

    def _start(self) -> "SimulatedScaleBoard":
        self.build = build()
        os.mkfifo(self.control_path)
        cmd = [str(self.build.board), "--elf", str(self.build.elf), "--eeprom", str(self.eeprom_path),
               "--control", str(self.control_path), *self.config.args()]
        self._log = open(Path(self._tmp.name, "board.log"), "w")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     start_new_session=True)
        line = self._read_first_line()
        try:
            info = json.loads(line)
            self.port = str(info["port"])
        except (ValueError, KeyError):
            err = self._stop_and_collect_stderr()
            raise NotConnected(f"the simulated board did not start (said {line!r}; {err})",
                               device="scale firmware") from None
        # O_RDWR would also work; O_WRONLY on a FIFO the board holds open never blocks.
        self._control = os.open(self.control_path, os.O_WRONLY | os.O_NONBLOCK)
        return self

    def _read_first_line(self) -> str:
        assert self.proc is not None and self.proc.stdout is not None
        stdout = self.proc.stdout
        result: list[str] = []
        reader = threading.Thread(target=lambda: result.append(stdout.readline()), daemon=True)
        reader.start()
        reader.join(self.start_timeout_s)
        return result[0].strip() if result else ""

    def _stop_and_collect_stderr(self) -> str:
        if self.proc is None:
            return ""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(5)
        self._log.flush()
        err = Path(self._tmp.name, "board.log").read_text(errors="replace")
        return " ".join(err.strip().splitlines()[-3:])

    # -- control ------------------------------------------------------------------------------
    def _send(self, command: str) -> None:
        if self._control is None or self.proc is None or self.proc.poll() is not None:
            raise NotConnected("the simulated board is not running", device="scale firmware")
        try:
            os.write(self._control, (command + "\n").encode("ascii"))
        except BlockingIOError:
            raise NotConnected("the simulated board does not read its control FIFO (stalled?)",
                               device="scale firmware") from None

    def set_force_n(self, force_n: float) -> None:
        """The downward force on the load cell from now on, in newtons."""
        f = float(force_n)
        if not (abs(f) < 1e9):
            raise ValueError(f"force_n={force_n!r} must be a finite number of newtons")
        self._send(f"force_n {f!r}")

    def set_mass_g(self, mass_g: float) -> None:
        """A mass on the platform, in grams (its weight at standard gravity)."""
        self.set_force_n(float(mass_g) * 1e-3 * sp.STANDARD_GRAVITY_MPS2)

    def set_hx711_connected(self, connected: bool) -> None:
        """Plug the HX711 in or pull it off (its DOUT then reads high through the pull-up)."""
        self._send("hx711 connect" if connected else "hx711 disconnect")

    def reset(self) -> None:
        """Pulse the reset line (a reboot without reopening the port)."""
        self._send("reset")

    def stats(self, timeout_s: float = 5.0) -> dict[str, Any]:
        """The board's counters: HX711 conversions, reads and timing violations, UART bytes, pacing."""
        self._stats_n += 1
        path = Path(self._tmp.name, f"stats{self._stats_n}.json")
        self._send(f"stats {path}")
        deadline = time.monotonic() + timeout_s
        while not path.exists():
            if time.monotonic() > deadline:
                raise NotConnected(f"the simulated board did not report its stats within {timeout_s} s",
                                   device="scale firmware")
            time.sleep(0.005)
        return json.loads(path.read_text())

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._control is not None:
            os.close(self._control)
            self._control = None
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.send_signal(signal.SIGTERM)
                try:
                    self.proc.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(timeout_s)
            if self.proc.stdout is not None:
                self.proc.stdout.close()
            self.proc = None
        if self._log is not None:
            self._log.close()
            self._log = None
        self._tmp.cleanup()

    def __enter__(self) -> "SimulatedScaleBoard":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def exit_reason(self) -> str:
        """Why the board process ended (its exit code and last log lines), for an error message."""
        code = self.proc.poll() if self.proc is not None else None
        log = Path(self._tmp.name, "board.log")
        tail = " ".join(log.read_text(errors="replace").strip().splitlines()[-3:]) if log.exists() else ""
        return f"exit code {code}; {tail}".strip()

    def describe(self) -> dict[str, Any]:
        """What ``tactile-rig mock serve scale --firmware`` prints next to the port."""
        return {"rate_sps": self.config.rate_sps, "boot_s": self.config.bootloader_s,
                "firmware": "arduino_scale", "simulated": "ATmega328P 16 MHz (libsimavr) + HX711",
                "control": str(self.control_path), "eeprom": str(self.eeprom_path),
                "flash_bytes": self.build.flash_bytes if self.build else None}
