"""The scale's real firmware on a simulated Arduino Uno: build it, run it, talk to it.

``firmware/arduino_scale/arduino_scale.ino`` is compiled for the ATmega328P with avr-gcc and the
Debian Arduino core (``firmware/arduino_scale/Makefile``); ``firmware/sim/scale_board.c`` runs the
``.elf`` on libsimavr with a modelled HX711, the Uno's DTR auto-reset and bootloader, and its
EEPROM kept in a file. Both are built on demand into a cache directory (``$TACTILE_RIG_CACHE``, else
``$XDG_CACHE_HOME/tactile-rig``, else ``~/.cache/tactile-rig``), keyed by a hash of their sources
and compilers, so nothing binary is committed.

Two ways to run it:

* :class:`SimulatedScaleBoard` serves the board on a pty in real time (a separate process), like
  ``tactile-rig mock serve scale`` serves the Python mock: any client opens ``board.port``; the
  load is set through a control FIFO (:meth:`SimulatedScaleBoard.set_force_n`).
* :func:`run_script` plays a timed host script against the board as fast as the simulator runs
  (no pty, no wall clock) and returns every line the host would have received with its simulated
  time: deterministic, for comparing the firmware with the mock line for line.

Needs ``apt-get install gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev libelf-dev``;
:func:`missing_toolchain` says what is absent.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from tactile_rig.core.errors import NotConnected, RigError
from tactile_rig.devices import scale as sp
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.sim.world.load_cell import LoadCell

#: Debian packages the firmware build and the simulated board need.
APT_PACKAGES = ("gcc-avr", "avr-libc", "arduino-core-avr", "simavr", "libsimavr-dev", "libelf-dev")
INSTALL_HINT = "apt-get install " + " ".join(APT_PACKAGES)
#: Set to 1 (CI does) to turn "toolchain missing" skips in the test suite into failures.
REQUIRE_ENV = "TACTILE_RIG_REQUIRE_FIRMWARE"
ARDUINO_DIR = Path(os.environ.get("TACTILE_RIG_ARDUINO_DIR", "/usr/share/arduino/hardware/arduino/avr"))
FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
SKETCH_DIR = FIRMWARE_DIR / "arduino_scale"
BOARD_DIR = FIRMWARE_DIR / "sim"
#: The Uno's optiboot after an external reset (see scale_board.c): what the board is silent for.
BOOTLOADER_S = 1.529
CPU_HZ = 16_000_000


class FirmwareUnavailable(RigError, RuntimeError):
    """The AVR toolchain, the Arduino core or libsimavr is missing, or the firmware sources are."""


class FirmwareBuildError(RigError, RuntimeError):
    """The sketch or the simulated board did not compile (the compiler's last lines are included)."""


def _which_all(names: Sequence[str]) -> list[str]:
    return [n for n in names if shutil.which(n) is None]


def missing_toolchain() -> list[str]:
    """What the firmware build and the simulated board need but cannot find (empty: all there)."""
    missing = _which_all(("avr-gcc", "avr-g++", "avr-objcopy", "avr-size", "make", "cc"))
    if not (ARDUINO_DIR / "cores" / "arduino" / "Arduino.h").is_file():
        missing.append(f"Arduino AVR core ({ARDUINO_DIR})")
    if not Path("/usr/include/simavr/sim_avr.h").is_file():
        missing.append("libsimavr headers (/usr/include/simavr)")
    if not any(Path(d, "libelf.so").exists() for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu",
                                                       "/usr/lib64", "/usr/lib")):
        missing.append("libelf (libelf-dev)")
    if not (SKETCH_DIR / "arduino_scale.ino").is_file() or not (BOARD_DIR / "scale_board.c").is_file():
        missing.append(f"firmware sources ({FIRMWARE_DIR}: run from a checkout of the project)")
    return missing


def toolchain_problem() -> str | None:
    """One line naming what is missing and how to install it, or None when the firmware can run."""
    missing = missing_toolchain()
    if not missing:
        return None
    return f"the simulated firmware needs {', '.join(missing)}: {INSTALL_HINT}"


def require_toolchain() -> None:
    """Raise :class:`FirmwareUnavailable` (one line, with the install command) unless all is there."""
    problem = toolchain_problem()
    if problem is not None:
        raise FirmwareUnavailable(problem, device="scale firmware")


# -- build ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FirmwareBuild:
    """The built sketch (``elf``, ``hex``) and simulated board (``board``); sizes in bytes."""

    elf: Path
    hex: Path
    board: Path
    flash_bytes: int
    ram_bytes: int
    directory: Path


def cache_root() -> Path:
    env = os.environ.get("TACTILE_RIG_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "tactile-rig"


def _tool_version(cmd: str) -> str:
    try:
        return subprocess.run([cmd, "--version"], capture_output=True, text=True, timeout=30).stdout.split("\n")[0]
    except (OSError, subprocess.SubprocessError):
        return "?"


def _build_key() -> str:
    h = hashlib.sha256()
    for path in (SKETCH_DIR / "arduino_scale.ino", SKETCH_DIR / "Makefile", BOARD_DIR / "scale_board.c",
                 BOARD_DIR / "Makefile"):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    for tool in ("avr-gcc", "cc"):
        h.update(_tool_version(tool).encode())
    h.update(str(ARDUINO_DIR).encode())
    return h.hexdigest()[:16]


def _make(directory: Path, build_dir: Path) -> str:
    cmd = ["make", "-C", str(directory), f"BUILD_DIR={build_dir}", f"ARDUINO_DIR={ARDUINO_DIR}"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        raise FirmwareBuildError(f"'{' '.join(cmd)}' took over 600 s", device="scale firmware") from None
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-15:])
        raise FirmwareBuildError(f"'{' '.join(cmd)}' failed:\n{tail}", device="scale firmware")
    return done.stdout


_build_lock = threading.Lock()


def build(*, force: bool = False) -> FirmwareBuild:
    """Compile the sketch and the simulated board into the cache (once per source version)."""
    require_toolchain()
    with _build_lock:
        out = cache_root() / "firmware" / _build_key()
        if force and out.exists():
            shutil.rmtree(out)
        if not (out / "build.json").is_file():
            out.parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=out.parent))
            try:
                report = _make(SKETCH_DIR, tmp / "sketch")
                _make(BOARD_DIR, tmp / "board")
                flash, ram = _parse_size(report)
                (tmp / "build.json").write_text(json.dumps({"flash_bytes": flash, "ram_bytes": ram}) + "\n")
                try:
                    os.rename(tmp, out)  # atomic: a concurrent build of the same key loses the race cleanly
                except OSError:
                    shutil.rmtree(tmp, ignore_errors=True)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        meta = json.loads((out / "build.json").read_text())
        return FirmwareBuild(elf=out / "sketch" / "arduino_scale.elf", hex=out / "sketch" / "arduino_scale.hex",
                             board=out / "board" / "scale_board", flash_bytes=int(meta["flash_bytes"]),
                             ram_bytes=int(meta["ram_bytes"]), directory=out)


def _parse_size(make_output: str) -> tuple[int, int]:
    for line in make_output.splitlines():
        if line.startswith("flash "):
            parts = line.split()
            return int(parts[1]), int(parts[6])
    raise FirmwareBuildError(f"no size report in the sketch build output:\n{make_output[-500:]}",
                             device="scale firmware")


# -- board parameters ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class BoardConfig:
    """What is on the simulated bench: the HX711's rate and the load cell seen through it.

    ``offset_counts`` and ``counts_per_g`` describe the bridge at gain 128, ``drift_counts`` its
    warm-up (reached with time constant ``drift_tau_s``), ``noise_counts`` the HX711's output noise
    (rms counts; the mock's per-rate default when None), ``spike_prob`` the chance of a glitched
    conversion: all as the Python mock has them. ``bootloader_s`` is the Uno's silence after a
    reset, ``boot_junk`` how many glitch bytes the host reads at a reset.
    """

    rate_sps: int = 80
    force_n: float = 0.0
    counts_per_g: float = sp.DEFAULT_CAL_FACTOR
    offset_counts: float = 84_000.0
    noise_counts: float | None = None
    drift_counts: float = 1_500.0
    drift_tau_s: float = 180.0
    spike_prob: float = 0.002
    channel_b_counts: float = 0.0
    bootloader_s: float = BOOTLOADER_S
    boot_junk: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if self.rate_sps not in sp.RATES_SPS:
            raise ValueError(f"scale firmware rate_sps={self.rate_sps!r}: an HX711 runs at 10 or 80")
        if not (0.0 <= self.bootloader_s <= 10.0):
            raise ValueError(f"scale firmware bootloader_s={self.bootloader_s!r} must be within [0, 10] s")
        if not (0 <= self.boot_junk <= 16):
            raise ValueError(f"scale firmware boot_junk={self.boot_junk!r} must be 0..16 bytes")
        if not (0.0 <= self.spike_prob <= 1.0):
            raise ValueError(f"scale firmware spike_prob={self.spike_prob!r} must be a probability in [0, 1]")
        if not (0.0 < self.drift_tau_s < 1e9):
            raise ValueError(f"scale firmware drift_tau_s={self.drift_tau_s!r} must be a positive number of seconds")
        for name in ("force_n", "counts_per_g", "offset_counts", "channel_b_counts", "drift_counts"):
            v = getattr(self, name)
            if not (abs(v) < 1e12):  # rejects NaN and inf too
                raise ValueError(f"scale firmware {name}={v!r} must be a finite number")
        if self.noise_counts is not None and not (0.0 <= self.noise_counts < 1e7):
            raise ValueError(f"scale firmware noise_counts={self.noise_counts!r} must be >= 0 counts")

    @property
    def noise(self) -> float:
        # The mock's default: HX711 input noise roughly doubles from 10 to 80 SPS.
        if self.noise_counts is not None:
            return float(self.noise_counts)
        return 20.0 if self.rate_sps == 10 else 40.0

    def args(self) -> list[str]:
        return ["--rate", str(self.rate_sps), "--force-n", repr(float(self.force_n)),
                "--counts-per-g", repr(float(self.counts_per_g)), "--offset-counts", repr(float(self.offset_counts)),
                "--noise-counts", repr(self.noise), "--channel-b-counts", repr(float(self.channel_b_counts)),
                "--drift-counts", repr(float(self.drift_counts)), "--drift-tau-s", repr(float(self.drift_tau_s)),
                "--spike-prob", repr(float(self.spike_prob)),
                "--bootloader-ms", repr(self.bootloader_s * 1000.0), "--boot-junk", str(self.boot_junk),
                "--seed", str(int(self.seed) & 0xFFFFFFFFFFFFFFFF)]


# -- scripted runs (deterministic, no pty) --------------------------------------------------------------

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


# -- the board on a pty, in real time -------------------------------------------------------------------

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


# -- the same script against the Python mock ------------------------------------------------------------

def _mock_for(config: BoardConfig) -> ScaleMock:
    return ScaleMock(clock=None, load_cell=LoadCell(applied_force_n=config.force_n), rate_sps=config.rate_sps,
                     boot_s=config.bootloader_s, noise_counts=config.noise, drift_counts=config.drift_counts,
                     drift_tau_s=config.drift_tau_s, spike_prob=config.spike_prob,
                     boot_junk=config.boot_junk > 0, counts_per_g=config.counts_per_g,
                     offset_counts=config.offset_counts, seed=config.seed)


def run_script_mock(script: Script, config: BoardConfig | None = None) -> ScriptResult:
    """Play ``script`` against the Python mock (:class:`~tactile_rig.mocks.scale.ScaleMock`) in
    virtual time, with the board's parameters; the result has the same shape as :func:`run_script`."""
    config = config or BoardConfig()
    mock = _mock_for(config)
    lines: list[HostLine] = []
    partial = bytearray()
    t_first = 0.0

    def collect(t: float) -> None:
        nonlocal t_first
        mock.advance_to(t)
        bt = mock.byte_time_s() if mock.timing else 0.0
        while mock._out:
            chunk = mock._out[0]
            n = len(chunk.data)
            taken = 0
            for i in range(n):
                t_end = chunk.ready_s - (n - 1 - i) * bt
                if t_end > t:
                    break
                if not partial:
                    t_first = t_end
                partial.append(chunk.data[i])
                taken += 1
                if chunk.data[i] == 0x0A:
                    lines.append(HostLine(bytes(partial), t_first, t_end))
                    partial.clear()
            if taken < n:
                chunk.data = chunk.data[taken:]
                break
            mock._out.popleft()

    for t, action, value in sorted(script.events, key=lambda e: e[0]):
        collect(t)
        if action == "open":
            mock.open(t)
        elif action == "close":
            mock.close(t)
            partial.clear()
        elif action == "reset":
            mock.inject("reset", t)
        elif action == "send":
            if mock.is_open:
                mock.feed(bytes(value), t)
        elif action == "force_n":
            mock.load_cell.applied_force_n = float(value)
        elif action == "hx711":
            mock.inject("hx711_connect" if value in (True, "connect") else "hx711_disconnect", t)
    collect(script.end_s)
    ee = {"cal_milli": mock.eeprom_cal_milli}
    return ScriptResult(lines, {"rx_dropped": mock.rx_dropped, "samples": mock.samples_sent, "eeprom": ee})


# -- the differential comparison ------------------------------------------------------------------------

#: How far apart (simulated seconds) the same line may start on the board and from the mock. The mock
#: models the sketch's compute times to ~0.05 ms; E,4 comes from millis(), which ticks every 1.024 ms.
LINE_TIME_TOLERANCE_S = 0.25e-3
E4_TIME_TOLERANCE_S = 1.5e-3


def _split_junk(data: bytes) -> tuple[bytes, bytes]:
    # The glitch bytes of a reset (>= 0x80) precede the banner on its line; they are random on both sides.
    i = 0
    while i < len(data) and data[i] >= 0x80:
        i += 1
    return data[:i], data[i:]


@dataclass
class Comparison:
    """The same script on the board and on the mock: ``firmware`` and ``mock`` results side by side."""

    firmware: ScriptResult
    mock: ScriptResult

    def differences(self, *, limit: int = 20) -> list[str]:
        """Every line that differs in bytes (glitch bytes aside) or in time beyond the tolerances."""
        out: list[str] = []
        a, b = self.firmware.lines, self.mock.lines
        if len(a) != len(b):
            out.append(f"{len(a)} lines from the firmware, {len(b)} from the mock")
        for i, (x, y) in enumerate(zip(a, b)):
            jx, dx = _split_junk(x.data)
            jy, dy = _split_junk(y.data)
            tol = E4_TIME_TOLERANCE_S if dx.startswith(b"E,4,") else LINE_TIME_TOLERANCE_S
            if dx != dy or len(jx) != len(jy):
                out.append(f"line {i}: firmware {x.data!r} at {x.t_first_s:.6f} s, "
                           f"mock {y.data!r} at {y.t_first_s:.6f} s")
            elif abs(x.t_first_s - y.t_first_s) > tol:
                out.append(f"line {i} {dx[:24]!r}: firmware at {x.t_first_s:.6f} s, mock at {y.t_first_s:.6f} s "
                           f"({(y.t_first_s - x.t_first_s) * 1e3:+.3f} ms)")
            if len(out) >= limit:
                break
        return out

    def time_differences_s(self) -> dict[str, list[float]]:
        """mock - firmware start time of each identical line, by tag (B, S, T, K, I, E)."""
        out: dict[str, list[float]] = {}
        for x, y in zip(self.firmware.lines, self.mock.lines):
            dx, dy = _split_junk(x.data)[1], _split_junk(y.data)[1]
            if dx == dy and dx:
                out.setdefault(chr(dx[0]), []).append(y.t_first_s - x.t_first_s)
        return out


def compare(script: Script, config: BoardConfig | None = None) -> Comparison:
    """Run ``script`` on the simulated board and on the Python mock (simulated and virtual time)."""
    config = config or BoardConfig()
    return Comparison(run_script(script, config), run_script_mock(script, config))


def reference_session(config: BoardConfig | None = None) -> Script:
    """The session the firmware and the mock are held to: boot, readings under a load profile (steps
    and a ramp), tare, calibration with a known 200 g, a bad command and a bad mass, ``?``, a reboot
    and a port reopen."""
    config = config or BoardConfig()
    g = sp.STANDARD_GRAVITY_MPS2 * 1e-3  # newtons per gram
    period = 1.0 / config.rate_sps
    window_s = (sp.SMOOTHING_SAMPLES + 2) * period
    boot_s = config.bootloader_s + 24 * period + 0.05  # the banner and a first sample are in
    s = Script().at(0.0, "open")
    t = boot_s
    s.at(t + 0.10, "force_n", 50 * g)
    for i in range(10):  # a 0.3 s ramp from 50 g to 150 g
        s.at(t + 0.30 + 0.03 * i, "force_n", (60 + 10 * i) * g)
    t += 0.6 + window_s
    s.at(t, "send", b"t\n")  # tare the 150 g of tray
    t += window_s + 0.3
    s.at(t, "force_n", 350 * g)  # + the known 200 g
    t += window_s + 0.2
    s.at(t, "send", b"c,200.000\n")
    t += window_s + 0.2
    s.at(t, "send", b"x\n").at(t + 0.05, "send", b"c,abc\n").at(t + 0.10, "send", b"?\n")
    t += 0.3
    s.at(t, "reset")  # a reboot with the load on: raw stays absolute, grams restart from the boot tare
    t += boot_s + 0.2
    s.at(t, "close").at(t + 0.1, "open")  # the host reopens the port: DTR resets the board
    s.end_s = t + 0.1 + boot_s + 0.2
    return s
