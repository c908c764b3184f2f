"""Build the preload library (``preload.c``, shipped with the package) with the system C compiler,
once per source version, into the native build cache (:mod:`tactile_rig.mocks.native_build`:
``$TACTILE_RIG_CACHE``, else ``$XDG_CACHE_HOME/tactile-rig``, else ``~/.cache/tactile-rig``), under a
key hashing the source, the flags and the compiler's version.

Needs ``apt-get install gcc libc6-dev`` (``cc``, the C library's headers and ``linux/videodev2.h``);
:func:`toolchain_problem` says what is missing in one line.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import tactile_rig.mocks.native_build as native_build
from tactile_rig.core.errors import RigError

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


def build_key() -> str:
    """The cache key: the source, the flags and the compiler's version."""
    return native_build.build_key([SOURCE], [" ".join(CFLAGS + LIBS), native_build.tool_version("cc")])


def _compile(out: Path) -> None:
    native_build.run_build_command(["cc", *CFLAGS, "-o", str(out / LIBRARY_NAME), str(SOURCE), *LIBS],
                                   timeout_s=300, error=PreloadBuildError, device="v4l2 preload")


def build(*, force: bool = False) -> Path:
    """The compiled library (built into the cache on first use of this source version)."""
    problem = toolchain_problem()
    if problem is not None:
        raise PreloadUnavailable(problem, device="v4l2 preload")
    return native_build.cached_build("v4l2", build_key(), _compile, complete=LIBRARY_NAME, force=force) / LIBRARY_NAME
