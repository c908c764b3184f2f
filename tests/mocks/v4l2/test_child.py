"""run_in_child: a function in a fresh interpreter with an environment, its result or its error back."""

from __future__ import annotations

import time

import numpy as np
import pytest

from tactile_rig.mocks.v4l2.child import ChildFailed, run_in_child
from tests._child_bodies import env_value, exit_hard, raise_unpicklable, raise_value_error, sleep_s


def test_the_child_sees_the_environment_and_returns_arrays() -> None:
    assert run_in_child(env_value, "TACTILE_RIG_CHILD_PROBE", env={"TACTILE_RIG_CHILD_PROBE": "42"}) == "42"
    assert run_in_child(env_value, "TACTILE_RIG_CHILD_PROBE") is None
    a = np.arange(12, dtype=np.uint16).reshape(3, 4)
    assert np.array_equal(run_in_child(np.ascontiguousarray, a), a)


def test_an_error_in_the_child_is_raised_again_with_its_traceback() -> None:
    with pytest.raises(ValueError, match="bad value 7") as info:
        run_in_child(raise_value_error, "bad value 7")
    assert any("raise_value_error" in note for note in info.value.__notes__)


def test_an_error_that_cannot_come_back_is_a_child_failure() -> None:
    with pytest.raises(ChildFailed, match="Unpicklable: no way back"):
        run_in_child(raise_unpicklable, "no way back")


def test_a_child_that_dies_or_hangs_is_a_child_failure() -> None:
    with pytest.raises(ChildFailed, match=r"exited with 3 without a result; its stderr ends:\ngoing down"):
        run_in_child(exit_hard, 3)
    t = time.monotonic()
    with pytest.raises(ChildFailed, match="did not finish within 0.5 s"):
        run_in_child(sleep_s, 30.0, timeout_s=0.5)
    assert time.monotonic() - t < 5.0
