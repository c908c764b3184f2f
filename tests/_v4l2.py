"""The emulated V4L2 cameras' test gate and helpers.

Without a C compiler, the C library's headers or v4l-utils the tests skip with one line naming
the Debian packages; with ``TACTILE_RIG_REQUIRE_V4L2=1`` (CI sets it) that skip is a failure.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pytest

from tactile_rig.mocks.v4l2 import V4L2Camera, build

APT_PACKAGES = "gcc libc6-dev v4l-utils"

# The uvcvideo generations the tests pin (see tactile_rig/mocks/v4l2/device.py): Debian 12's kernel,
# before uvcvideo refused inactive controls itself and with its privilege scheme; and a current one.
KERNEL_6_1 = (6, 1)
KERNEL_CURRENT = (6, 18)


def require(*tools: str) -> None:
    """Skip (fail under TACTILE_RIG_REQUIRE_V4L2=1) unless the preload library can be built and
    ``tools`` (e.g. ``v4l2-ctl``) are on PATH."""
    missing = build.missing_toolchain() + [t for t in tools if shutil.which(t) is None]
    if not missing:
        return
    problem = f"the V4L2 camera emulation tests need {', '.join(missing)}: apt-get install {APT_PACKAGES}"
    if os.environ.get(build.REQUIRE_ENV) == "1":
        pytest.fail(f"{build.REQUIRE_ENV}=1 but {problem}", pytrace=False)
    pytest.skip(problem)


@contextmanager
def emulated(model: str = "c310", **kwargs: Any) -> Iterator[V4L2Camera]:
    """A started emulated camera in a registry of its own (a short path: its sockets live there)."""
    require()
    registry = Path(tempfile.mkdtemp(prefix="trv-"))
    cam = V4L2Camera(model, registry=registry, **kwargs)
    try:
        with cam:
            yield cam
    finally:
        shutil.rmtree(registry, ignore_errors=True)


def run(cam: V4L2Camera, *argv: str, timeout_s: float = 60.0, check: bool = True) -> subprocess.CompletedProcess[str]:
    """Run a command in a process started with the camera's environment (the preload and the registry)."""
    env = dict(os.environ)
    env.update(cam.env)
    done = subprocess.run(list(argv), capture_output=True, text=True, env=env, timeout=timeout_s)
    if check and done.returncode != 0:
        raise AssertionError(f"{' '.join(argv)} exited with {done.returncode}:\n{done.stdout[-3000:]}\n"
                             f"{done.stderr[-3000:]}")
    return done


def v4l2_ctl(cam: V4L2Camera, *args: str, **kwargs: Any) -> subprocess.CompletedProcess[str]:
    require("v4l2-ctl")
    return run(cam, "v4l2-ctl", "-d", cam.port, *args, **kwargs)
