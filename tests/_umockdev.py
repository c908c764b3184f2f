"""The umockdev tests' gate and runner: a child process under ``umockdev-run`` with a testbed file.

umockdev's preload library has to be in a process from its start, so what runs "under umockdev" is
always a child process: :func:`probe` runs ``tests/_usb_probe.py`` there once per bench and returns
everything the tests look at (``tactile-rig devices`` as JSON and as a table, discovery through
libusb and through sysfs alone, pyusb's walk of every configuration over libusb, the testbed's
``/sys`` file by file, ``lsusb -v``), since building a testbed costs seconds on a disk.

Without ``umockdev-run`` or libusb the tests skip with one line naming the Debian packages; with
``TACTILE_RIG_REQUIRE_UMOCKDEV=1`` (CI sets it) that skip is a failure instead. ``lsusb`` (Debian
``usbutils``) judges the descriptors the same way.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest

from tactile_rig.mocks.usb.bench import BENCH, Bench
from tactile_rig.mocks.usb.testbed import REQUIRE_ENV, umockdev_problem, write_testbed

PROBE = Path(__file__).with_name("_usb_probe.py")


def _gate(problem: str | None) -> None:
    if problem is None:
        return
    if os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"{REQUIRE_ENV}=1 but {problem}", pytrace=False)
    pytest.skip(problem)


def require_umockdev() -> None:
    """Skip (or fail, when required) unless umockdev-run and libusb are installed."""
    _gate(umockdev_problem())


def require_lsusb() -> None:
    """Skip (or fail, when required) unless lsusb is installed, besides umockdev."""
    require_umockdev()
    _gate(None if shutil.which("lsusb") else "lsusb not found; install the Debian package usbutils")


def run(testbed_file: Path, argv: list[str], *, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    """``argv`` under ``umockdev-run --device testbed_file``; its output captured."""
    return subprocess.run(["umockdev-run", "--device", str(testbed_file), "--", *argv], capture_output=True,
                          text=True, timeout=timeout_s, check=False)


def probe(bench: Bench = BENCH) -> dict[str, Any]:
    """What ``tests/_usb_probe.py`` sees of ``bench`` under umockdev (one testbed, one run per session)."""
    require_umockdev()
    return _probe(bench)


@functools.lru_cache(maxsize=None)
def _probe(bench: Bench) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="tactile-rig-usb-") as tmp:
        testbed = write_testbed(Path(tmp) / "bench.umockdev", bench)
        done = run(testbed, [sys.executable, str(PROBE)])
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)
