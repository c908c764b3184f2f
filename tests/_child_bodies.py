"""Bodies for the tests of :func:`tactile_rig.mocks.v4l2.child.run_in_child` (standard library only)."""

from __future__ import annotations

import os
import sys
import time
from typing import Any


def env_value(name: str) -> str | None:
    return os.environ.get(name)


class Unpicklable(Exception):
    def __init__(self, message: str, handle: Any) -> None:
        super().__init__(message)
        self.handle = handle


def raise_value_error(message: str) -> None:
    raise ValueError(message)


def raise_unpicklable(message: str) -> None:
    raise Unpicklable(message, lambda: None)


def exit_hard(code: int) -> None:
    sys.stderr.write("going down\n")
    sys.stderr.flush()
    os._exit(code)


def sleep_s(seconds: float) -> None:
    time.sleep(seconds)
