"""The sketch builds for an Uno with the Debian toolchain, as an ordinary Arduino sketch."""

from __future__ import annotations

import re
import shutil

import pytest

from tactile_rig.mocks import scale_firmware as sf
from tests._firmware import firmware_build

UNO_FLASH_BYTES = 32_256  # 32 KiB less optiboot's 512 bytes
UNO_RAM_BYTES = 2_048


@pytest.fixture(scope="module")
def firmware():
    """The compiled sketch and board (skip, or fail under TACTILE_RIG_REQUIRE_FIRMWARE=1, without them)."""
    return firmware_build()


def _ihex_bytes(path) -> int:
    total = 0
    for line in path.read_text().splitlines():
        rec = bytes.fromhex(line[1:])
        assert line[0] == ":" and sum(rec) % 256 == 0 and rec[0] + 5 == len(rec), line
        if rec[3] == 0:
            total += rec[0]
    return total


def test_the_sketch_fits_an_uno_and_its_hex_is_what_gets_flashed(firmware) -> None:
    assert 2_000 < firmware.flash_bytes < UNO_FLASH_BYTES
    assert firmware.ram_bytes < UNO_RAM_BYTES // 2  # the rest is stack and the serial buffers' headroom
    assert _ihex_bytes(firmware.hex) == firmware.flash_bytes
    assert firmware.elf.read_bytes()[:4] == b"\x7fELF" and firmware.board.exists()


def test_a_second_build_comes_from_the_cache(firmware) -> None:
    again = sf.build()
    assert again.directory == firmware.directory and again.elf.stat().st_mtime == firmware.elf.stat().st_mtime


def test_it_is_an_ordinary_sketch_with_no_third_party_library() -> None:
    source = (sf.SKETCH_DIR / "arduino_scale.ino").read_text()
    includes = set(re.findall(r"^#include\s+[<\"]([^>\"]+)[>\"]", source, flags=re.M))
    assert includes <= {"EEPROM.h", "avr/sleep.h", "avr/interrupt.h"}  # all ship with the Arduino IDE
    assert re.search(r"^void setup\(\)", source, flags=re.M) and re.search(r"^void loop\(\)", source, flags=re.M)


def test_without_the_toolchain_the_problem_names_what_to_install(monkeypatch) -> None:
    monkeypatch.setattr(shutil, "which", lambda name: None)
    problem = sf.toolchain_problem()
    assert problem is not None and "avr-gcc" in problem and sf.INSTALL_HINT in problem
    with pytest.raises(sf.FirmwareUnavailable, match="apt-get install gcc-avr"):
        sf.require_toolchain()
