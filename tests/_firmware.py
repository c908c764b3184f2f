"""The firmware tests' gate: the compiled sketch and the simulated board, or a one-line skip.

Without the AVR toolchain and libsimavr the tests skip, saying what to install; with
``TACTILE_RIG_REQUIRE_FIRMWARE=1`` (CI sets it) that skip is a failure instead.
"""

from __future__ import annotations

import os

import pytest

from tactile_rig.mocks import scale_firmware as sf


def firmware_build() -> sf.FirmwareBuild:
    """The cached build of the sketch and the board; skip (or fail, when required) without a toolchain."""
    problem = sf.toolchain_problem()
    if problem is not None:
        if os.environ.get(sf.REQUIRE_ENV) == "1":
            pytest.fail(f"{sf.REQUIRE_ENV}=1 but {problem}", pytrace=False)
        pytest.skip(problem)
    return sf.build()

