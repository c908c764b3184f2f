"""A loop that serves a mock on a daemon thread of its own, as the pty server and the pty relay do.

:class:`LoopThread` owns the thread's life: :meth:`~LoopThread.start` (idempotent), :meth:`~LoopThread.stop`
(sets the stop flag, joins, then releases what the subclass holds), the context manager, and what
ended the loop: an exception inside it never dies silently, it is kept in :attr:`~LoopThread.error`
and logged. A subclass implements :meth:`~LoopThread._once` (one pass of its loop) and, where it
needs them, the hooks around it.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, TypeVar

__all__ = ["LoopThread"]

T = TypeVar("T", bound="LoopThread")


class LoopThread:
    """A loop on its own daemon thread, named ``thread_name``; ``error`` holds what stopped it."""

    def __init__(self, thread_name: str, log: logging.Logger) -> None:
        self._thread_name = thread_name
        self._log = log
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def start(self: T) -> T:
        """Open what the loop needs (:meth:`_before_start`) and run it; a second call does nothing."""
        if self._thread is None:
            self._before_start()
            self._thread = threading.Thread(target=self._run, name=self._thread_name, daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the loop, wait up to ``timeout_s`` for it, then release what it held (:meth:`_after_stop`)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
        self._after_stop()

    def __enter__(self: T) -> T:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            self._on_thread_start()
            while not self._stop.is_set():
                self._once()
        except BaseException as exc:  # surfaced through .error; the thread must not die silently
            self.error = exc
            self._log.exception("%s stopped", self._thread_name)

    # -- what a subclass provides --------------------------------------------------------------------
    def _once(self) -> None:
        """One pass of the loop (it returns often enough for :meth:`stop` to be seen)."""
        raise NotImplementedError

    def _before_start(self) -> None:
        """In the caller's thread, before the loop starts."""

    def _on_thread_start(self) -> None:
        """In the loop's thread, before its first pass."""

    def _after_stop(self) -> None:
        """After the loop has stopped (or been given up on): release what it held."""
