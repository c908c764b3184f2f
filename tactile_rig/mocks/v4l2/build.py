"""Build the preload library (``preload.c``, shipped with the package) with the system C compiler,
once per source version, into the cache (``$TACTILE_RIG_CACHE``, else ``$XDG_CACHE_HOME/tactile-rig``,
else ``~/.cache/tactile-rig``), under a key hashing the source, the flags and the compiler's version.

Needs ``apt-get install gcc libc6-dev`` (``cc``, the C library's headers and ``linux/videodev2.h``);
:func:`toolchain_problem` says what is missing in one line.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

from tactile_rig.core.errors import RigError
from tactile_rig.mocks.scale_firmware import cache_root

SOURCE = Path(__file__).resolve().parent / "preload.c"
LIBRARY_NAME = "libtactile_rig_v4l2.so"
APT_PACKAGES = ("gcc", "libc6-dev")
INSTALL_HINT = "apt-get install " + " ".join(APT_PACKAGES)
#: Set to 1 (CI does) to turn "toolchain or v4l-utils missing" skips in the test suite into failures.
REQUIRE_ENV = "TACTILE_RIG_REQUIRE_V4L2"
CFLAGS = ("-O2", "-g", "-Wall", "-Wextra", "-Wno-nonnull-compare", "-Wno-format-truncation",
          "-fno-delete-null-pointer-checks", "-fPIC", "-shared", "-fvisibility=hidden", "-pthread")
LIBS = ("-ldl",)


class PreloadUnavailable(RigError, RuntimeError):
    """The C compiler or the C library's headers are missing, or the source is."""


class PreloadBuildError(RigError, RuntimeError):
    """``preload.c`` did not compile (the compiler's last lines are included)."""


def missing_toolchain() -> list[str]:
    """What building the library needs but cannot find (empty: all there)."""
    missing = []
    if shutil.which("cc") is None:
        missing.append("a C compiler (cc)")
    for header in ("/usr/include/stdio.h", "/usr/include/linux/videodev2.h"):
        if not Path(header).is_file():
            missing.append(f"the C library's headers ({header})")
            break
    if not SOURCE.is_file():
        missing.append(f"the library's source ({SOURCE})")
    return missing


def toolchain_problem() -> str | None:
    """One line naming what is missing and how to install it, or None when the library can be built."""
    missing = missing_toolchain()
    if not missing:
        return None
    return f"the V4L2 camera emulation needs {', '.join(missing)}: {INSTALL_HINT}"


def _compiler_version() -> str:
    try:
        return subprocess.run(["cc", "--version"], capture_output=True, text=True, timeout=30).stdout.split("\n")[0]
    except (OSError, subprocess.SubprocessError):
        return "?"


def build_key() -> str:
    h = hashlib.sha256()
    h.update(SOURCE.read_bytes())
    h.update(" ".join(CFLAGS + LIBS).encode())
    h.update(_compiler_version().encode())
    return h.hexdigest()[:16]


_lock = threading.Lock()


def build(*, force: bool = False) -> Path:
    """The compiled library (built into the cache on first use of this source version)."""
    problem = toolchain_problem()
    if problem is not None:
        raise PreloadUnavailable(problem, device="v4l2 preload")
    with _lock:
        out = cache_root() / "v4l2" / build_key()
        lib = out / LIBRARY_NAME
        if force and out.exists():
            shutil.rmtree(out)
        if lib.is_file():
            return lib
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=out.parent))
        try:
            cmd = ["cc", *CFLAGS, "-o", str(tmp / LIBRARY_NAME), str(SOURCE), *LIBS]
            try:
                done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
            except subprocess.TimeoutExpired:
                raise PreloadBuildError(f"'{' '.join(cmd)}' took over 300 s", device="v4l2 preload") from None
            if done.returncode != 0:
                tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-15:])
                raise PreloadBuildError(f"'{' '.join(cmd)}' failed:\n{tail}", device="v4l2 preload")
            try:
                os.rename(tmp, out)  # atomic: a concurrent build of the same key loses the race cleanly
            except OSError:
                shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return lib
