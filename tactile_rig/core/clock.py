"""Clocks: everything in tactile-rig that waits takes a :class:`Clock`.

:class:`RealClock` is wall time (``time.monotonic``) for the bench. :class:`VirtualClock` advances
only when someone sleeps on it (or calls :meth:`VirtualClock.advance`), so a closed-loop episode
that would take a minute on the bench runs in milliseconds, deterministically. Simulated devices
and world models read ``clock.now_s()`` lazily and integrate their state up to it.
"""

from __future__ import annotations

import datetime as _dt
import threading
import time
from typing import Callable, Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """A source of time in seconds and a way to wait."""

    def now_s(self) -> float:
        """Monotonic time in seconds (arbitrary origin)."""
        ...

    def sleep(self, dt_s: float) -> None:
        """Wait ``dt_s`` seconds (no-op for ``dt_s <= 0``)."""
        ...

    @property
    def is_virtual(self) -> bool:
        """True when time only advances through :meth:`sleep` (simulation)."""
        ...


class RealClock:
    """Wall time: ``time.monotonic`` and ``time.sleep``."""

    is_virtual = False

    def now_s(self) -> float:
        return time.monotonic()

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            time.sleep(dt_s)

    def __repr__(self) -> str:
        return "RealClock()"


class VirtualClock:
    """Simulated time that advances only on :meth:`sleep` / :meth:`advance`.

    Thread-safe. Listeners registered with :meth:`on_advance` are called with the new time after
    every advance (world models usually integrate lazily instead, which is cheaper).
    """

    is_virtual = True

    def __init__(self, start_s: float = 0.0) -> None:
        self._t_s = float(start_s)
        self._lock = threading.Lock()
        self._listeners: list[Callable[[float], None]] = []

    def now_s(self) -> float:
        with self._lock:
            return self._t_s

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            self.advance(dt_s)

    def advance(self, dt_s: float) -> float:
        """Move time forward by ``dt_s`` (must be ≥ 0) and return the new time in seconds."""
        if not dt_s >= 0:
            raise ValueError(f"dt_s={dt_s!r} must be >= 0 (a clock never goes back)")
        with self._lock:
            self._t_s += dt_s
            t = self._t_s
            listeners = list(self._listeners)
        for fn in listeners:
            fn(t)
        return t

    def advance_to(self, t_s: float) -> float:
        """Move time forward to ``t_s`` if it lies in the future; return the current time."""
        now = self.now_s()
        if t_s > now:
            return self.advance(t_s - now)
        return now

    def on_advance(self, fn: Callable[[float], None]) -> None:
        """Call ``fn(t_s)`` after each advance."""
        with self._lock:
            self._listeners.append(fn)

    def __repr__(self) -> str:
        return f"VirtualClock(t_s={self._t_s:.6f})"


class Deadline:
    """A point in time on a clock: ``remaining_s()`` and ``expired()``."""

    def __init__(self, clock: Clock, timeout_s: float | None) -> None:
        self.clock = clock
        self.timeout_s = timeout_s
        self.t_end_s = None if timeout_s is None else clock.now_s() + max(0.0, timeout_s)

    def remaining_s(self) -> float | None:
        """Seconds left (≥ 0), or ``None`` for no deadline."""
        if self.t_end_s is None:
            return None
        return max(0.0, self.t_end_s - self.clock.now_s())

    def expired(self) -> bool:
        return self.t_end_s is not None and self.clock.now_s() >= self.t_end_s


def utc_now() -> str:
    """The current UTC wall time as an ISO 8601 string to the second (calibration and run stamps)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
