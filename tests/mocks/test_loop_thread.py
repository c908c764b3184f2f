"""The serving loop's thread: started once, stopped with what it held released, its failure kept."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from tactile_rig.mocks.loop_thread import LoopThread

log = logging.getLogger("tests.loop_thread")


class _Counting(LoopThread):
    def __init__(self, fail_after: int | None = None) -> None:
        super().__init__("counting-loop", log)
        self.events: list[str] = []
        self.passes = 0
        self.fail_after = fail_after
        self.thread_names: set[str] = set()

    def _before_start(self) -> None:
        self.events.append(f"before_start in {threading.current_thread().name}")

    def _on_thread_start(self) -> None:
        self.events.append(f"thread_start in {threading.current_thread().name}")

    def _once(self) -> None:
        self.thread_names.add(threading.current_thread().name)
        self.passes += 1
        if self.fail_after is not None and self.passes > self.fail_after:
            raise OSError("the pty went away")
        time.sleep(0.001)

    def _after_stop(self) -> None:
        self.events.append("after_stop")


def _wait_for(cond, timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


def test_the_loop_runs_on_its_own_named_thread_between_start_and_stop() -> None:
    loop = _Counting()
    assert loop.start() is loop and loop.start() is loop  # a second start does nothing
    _wait_for(lambda: loop.passes >= 3)
    loop.stop()
    after = loop.passes
    time.sleep(0.02)
    assert loop.passes == after  # stopped
    assert loop.thread_names == {"counting-loop"} and loop.error is None
    main = threading.current_thread().name
    assert loop.events == [f"before_start in {main}", "thread_start in counting-loop", "after_stop"]


def test_an_exception_in_the_loop_is_kept_and_logged_not_lost(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.ERROR, logger="tests.loop_thread"):
        with _Counting(fail_after=2) as loop:
            _wait_for(lambda: loop.error is not None)
    assert isinstance(loop.error, OSError) and loop.passes == 3
    assert loop.events[-1] == "after_stop"  # the context manager released what it held
    assert any("counting-loop stopped" in r.getMessage() and r.exc_info for r in caplog.records)


def test_stop_without_start_releases_and_does_not_hang() -> None:
    loop = _Counting()
    loop.stop(timeout_s=0.1)
    assert loop.events == ["after_stop"] and loop.passes == 0
