"""The scale's real firmware on a simulated Arduino Uno: build it, run it, talk to it.

``firmware/arduino_scale/arduino_scale.ino`` is compiled for the ATmega328P with avr-gcc and the
Debian Arduino core (``firmware/arduino_scale/Makefile``); ``firmware/sim/scale_board.c`` runs the
``.elf`` on libsimavr with a modelled HX711, the Uno's DTR auto-reset and bootloader, and its
EEPROM kept in a file. Both are built on demand into the native build cache
(:mod:`tactile_rig.mocks.native_build`: ``$TACTILE_RIG_CACHE``, else ``$XDG_CACHE_HOME/tactile-rig``,
else ``~/.cache/tactile-rig``), keyed by a hash of their sources and compilers, so nothing binary is
committed.

Two ways to run it:

* :class:`SimulatedScaleBoard` serves the board on a pty in real time (a separate process), like
  ``tactile-rig mock serve scale`` serves the Python mock: any client opens ``board.port``; the
  load is set through a control FIFO (:meth:`SimulatedScaleBoard.set_force_n`).
* :func:`run_script` plays a timed host script against the board as fast as the simulator runs
  (no pty, no wall clock) and returns every line the host would have received with its simulated
  time: deterministic, for comparing the firmware with the mock line for line (:func:`compare`).

One module per job: :mod:`.toolchain` (what the build needs, the build), :mod:`.config` (the board's
parameters), :mod:`.script` (scripted runs), :mod:`.board` (the board on a pty), :mod:`.differential`
(the same script on the mock, and the comparison).

Needs ``apt-get install gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev libelf-dev``;
:func:`missing_toolchain` says what is absent.
"""

from __future__ import annotations

from tactile_rig.mocks.native_build import cache_root
from tactile_rig.mocks.scale_firmware.board import SimulatedScaleBoard
from tactile_rig.mocks.scale_firmware.config import BOOTLOADER_S, CPU_HZ, BoardConfig
from tactile_rig.mocks.scale_firmware.differential import (
    E4_TIME_TOLERANCE_S,
    LINE_TIME_TOLERANCE_S,
    Comparison,
    compare,
    reference_session,
    run_script_mock,
)
from tactile_rig.mocks.scale_firmware.script import HostLine, Script, ScriptResult, run_script
from tactile_rig.mocks.scale_firmware.toolchain import (
    APT_PACKAGES,
    ARDUINO_DIR,
    BOARD_DIR,
    FIRMWARE_DIR,
    INSTALL_HINT,
    REQUIRE_ENV,
    SKETCH_DIR,
    FirmwareBuild,
    FirmwareBuildError,
    FirmwareUnavailable,
    build,
    missing_toolchain,
    require_toolchain,
    toolchain_problem,
)

__all__ = [
    "APT_PACKAGES", "ARDUINO_DIR", "BOARD_DIR", "BOOTLOADER_S", "BoardConfig", "CPU_HZ", "Comparison",
    "E4_TIME_TOLERANCE_S", "FIRMWARE_DIR", "FirmwareBuild", "FirmwareBuildError", "FirmwareUnavailable", "HostLine",
    "INSTALL_HINT", "LINE_TIME_TOLERANCE_S", "REQUIRE_ENV", "SKETCH_DIR", "Script", "ScriptResult",
    "SimulatedScaleBoard", "build", "cache_root", "compare", "missing_toolchain", "reference_session",
    "require_toolchain", "run_script", "run_script_mock", "toolchain_problem",
]
