"""Build the scale's sketch and its simulated board on demand; say what is missing when they cannot be.

``firmware/arduino_scale/arduino_scale.ino`` is compiled for the ATmega328P with avr-gcc and the
Debian Arduino core (``firmware/arduino_scale/Makefile``); ``firmware/sim/scale_board.c`` (libsimavr
with a modelled HX711) with the system compiler. Both go into the native build cache
(:mod:`tactile_rig.mocks.native_build`), keyed by a hash of their sources and compilers, so nothing
binary is committed.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from tactile_rig.core.errors import RigError
from tactile_rig.mocks.native_build import build_key, cached_build, run_build_command, tool_version

#: Debian packages the firmware build and the simulated board need.
APT_PACKAGES = ("gcc-avr", "avr-libc", "arduino-core-avr", "simavr", "libsimavr-dev", "libelf-dev")
INSTALL_HINT = "apt-get install " + " ".join(APT_PACKAGES)
#: Set to 1 (CI does) to turn "toolchain missing" skips in the test suite into failures.
REQUIRE_ENV = "TACTILE_RIG_REQUIRE_FIRMWARE"
ARDUINO_DIR = Path(os.environ.get("TACTILE_RIG_ARDUINO_DIR", "/usr/share/arduino/hardware/arduino/avr"))
FIRMWARE_DIR = Path(__file__).resolve().parents[3] / "firmware"
SKETCH_DIR = FIRMWARE_DIR / "arduino_scale"
BOARD_DIR = FIRMWARE_DIR / "sim"
_DEVICE = "scale firmware"


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
        raise FirmwareUnavailable(problem, device=_DEVICE)


@dataclass(frozen=True)
class FirmwareBuild:
    """The built sketch (``elf``, ``hex``) and simulated board (``board``); sizes in bytes."""

    elf: Path
    hex: Path
    board: Path
    flash_bytes: int
    ram_bytes: int
    directory: Path


def _build_key() -> str:
    sources = (SKETCH_DIR / "arduino_scale.ino", SKETCH_DIR / "Makefile", BOARD_DIR / "scale_board.c",
               BOARD_DIR / "Makefile")
    return build_key(sources, [tool_version("avr-gcc"), tool_version("cc"), str(ARDUINO_DIR)])


def _make(directory: Path, build_dir: Path) -> str:
    return run_build_command(["make", "-C", str(directory), f"BUILD_DIR={build_dir}", f"ARDUINO_DIR={ARDUINO_DIR}"],
                             timeout_s=600, error=FirmwareBuildError, device=_DEVICE)


def _make_all(tmp: Path) -> None:
    report = _make(SKETCH_DIR, tmp / "sketch")
    _make(BOARD_DIR, tmp / "board")
    flash, ram = _parse_size(report)
    (tmp / "build.json").write_text(json.dumps({"flash_bytes": flash, "ram_bytes": ram}) + "\n")


def build(*, force: bool = False) -> FirmwareBuild:
    """Compile the sketch and the simulated board into the cache (once per source version)."""
    require_toolchain()
    out = cached_build("firmware", _build_key(), _make_all, complete="build.json", force=force)
    meta = json.loads((out / "build.json").read_text())
    return FirmwareBuild(elf=out / "sketch" / "arduino_scale.elf", hex=out / "sketch" / "arduino_scale.hex",
                         board=out / "board" / "scale_board", flash_bytes=int(meta["flash_bytes"]),
                         ram_bytes=int(meta["ram_bytes"]), directory=out)


def _parse_size(make_output: str) -> tuple[int, int]:
    for line in make_output.splitlines():
        if line.startswith("flash "):
            parts = line.split()
            return int(parts[1]), int(parts[6])
    raise FirmwareBuildError(f"no size report in the sketch build output:\n{make_output[-500:]}", device=_DEVICE)
