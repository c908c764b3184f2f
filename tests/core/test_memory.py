"""keep_freed_memory: a registration's buffers are reused, not faulted in afresh each call (glibc),
and the call answers False where there is nothing to set."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from tactile_rig.core import memory

_CODE = """
import resource, sys
import cv2, numpy as np
from tactile_rig.core import memory
if sys.argv[1] == "keep":
    assert memory.keep_freed_memory() and memory.keep_freed_memory()  # idempotent
from tactile_rig.perception.gelsight import register
z = cv2.GaussianBlur(np.random.default_rng(0).normal(0, 1, (240, 320)).astype(np.float32), (0, 0), 3.0)
z *= np.float32(0.5 / float(np.abs(z).max()))
b = np.roll(z, 3, axis=1)
register(z, b, 0.06)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    register(z, b, 0.06)
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 10)
"""


def _faults_per_call(mode: str) -> float:
    out = subprocess.run([sys.executable, "-c", _CODE, mode], capture_output=True, text=True, check=True)
    return float(out.stdout.strip())


def test_on_glibc_a_registration_stops_faulting_its_buffers_in() -> None:
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        pytest.skip("glibc only")
    plain, kept = _faults_per_call("plain"), _faults_per_call("keep")
    # Without it every call faults its 0.3 MB maps in again (hundreds of pages); with it, ~none.
    assert plain > 100 and kept < 0.1 * plain, (plain, kept)


def test_elsewhere_it_answers_false(monkeypatch) -> None:
    monkeypatch.setattr(memory, "_applied", False)
    monkeypatch.setattr(memory.platform, "system", lambda: "Darwin")
    assert memory.keep_freed_memory() is False
