"""Timed host scripts played against the firmware on the simulated board, as fast as the simulator
runs (no pty, no wall clock): every line the host would have received, with its simulated time.
Deterministic, for comparing the firmware with the mock line for line."""

from __future__ import annotations

import json
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tactile_rig.core.errors import NotConnected
from tactile_rig.mocks.scale_firmware.config import BoardConfig
from tactile_rig.mocks.scale_firmware.toolchain import build

__all__ = ["HostLine", "Script", "ScriptResult", "run_script"]


@dataclass(frozen=True)
class HostLine:
    """One line as the host received it: bytes (with ``\\r\\n``), first and last byte time in seconds."""

    data: bytes
    t_first_s: float
    t_last_s: float


@dataclass
class ScriptResult:
    lines: list[HostLine]
    stats: dict[str, Any]
    eeprom: bytes = b""


@dataclass
class Script:
    """A timed host session: ``at(t_s, action)`` with actions ``open``, ``close``, ``reset``,
    ``send`` (bytes), ``force_n`` (newtons), ``hx711`` ("connect"/"disconnect"); ``end_s`` closes it."""

    events: list[tuple[float, str, Any]] = field(default_factory=list)
    end_s: float = 0.0

    def at(self, t_s: float, action: str, value: Any = None) -> "Script":
        if action not in ("open", "close", "reset", "send", "force_n", "hx711"):
            raise ValueError(f"script action {action!r}: expected open, close, reset, send, force_n or hx711")
        if not (t_s >= 0.0 and t_s < 3600.0):
            raise ValueError(f"script time {t_s!r} s must be within [0, 3600)")
        self.events.append((float(t_s), action, value))
        self.end_s = max(self.end_s, float(t_s))
        return self

    def render(self) -> str:
        out = []
        for t, action, value in sorted(self.events, key=lambda e: e[0]):
            ms = f"{t * 1000.0:.6f}"
            if action == "send":
                out.append(f"{ms} send {bytes(value).hex()}")
            elif action == "force_n":
                out.append(f"{ms} force_n {float(value)!r}")
            elif action == "hx711":
                out.append(f"{ms} hx711 {'connect' if value in (True, 'connect') else 'disconnect'}")
            else:
                out.append(f"{ms} {action}")
        out.append(f"{self.end_s * 1000.0:.6f} end")
        return "\n".join(out) + "\n"


def run_script(script: Script, config: BoardConfig | None = None, *, eeprom: bytes | None = None,
               timeout_s: float = 120.0) -> ScriptResult:
    """Play ``script`` against the firmware on the simulated board; simulated time, not wall time."""
    config = config or BoardConfig()
    fw = build()
    with tempfile.TemporaryDirectory(prefix="scale-fw-") as tmp:
        script_path = Path(tmp, "session.txt")
        script_path.write_text(script.render())
        ee_path = Path(tmp, "eeprom.bin")
        if eeprom is not None:
            if len(eeprom) != 1024:
                raise ValueError(f"eeprom is {len(eeprom)} bytes: an ATmega328P has 1024")
            ee_path.write_bytes(eeprom)
        cmd = [str(fw.board), "--elf", str(fw.elf), "--eeprom", str(ee_path), "--script", str(script_path),
               *config.args()]
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise NotConnected(f"the simulated board ran over {timeout_s} s on a {script.end_s:.1f} s script",
                               device="scale firmware") from None
        if done.returncode != 0:
            raise NotConnected(f"the simulated board exited with {done.returncode}: {done.stderr.strip()[-300:]}",
                               device="scale firmware")
        lines: list[HostLine] = []
        stats: dict[str, Any] = {}
        for raw in done.stdout.splitlines():
            if raw.startswith("L "):
                _, t0, t1, hexdata = raw.split(" ", 3)
                lines.append(HostLine(bytes.fromhex(hexdata), float(t0) * 1e-6, float(t1) * 1e-6))
            elif raw.startswith("STATS "):
                stats = json.loads(raw[6:])
        ee = ee_path.read_bytes() if ee_path.exists() else b""
        return ScriptResult(lines, stats, ee)
