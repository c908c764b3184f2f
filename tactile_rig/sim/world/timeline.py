"""A short history of a model's state so a sensor can sample the world at a past capture time.

A simulated sensor with latency reports the world as it was when the frame was captured; the
models integrate lazily, so by the time the frame is read they are already past that instant.
Each model that a sensor looks at appends its state after every integration step here.
"""

from __future__ import annotations

import bisect
from typing import Generic, TypeVar

T = TypeVar("T")


class Timeline(Generic[T]):
    """Time-stamped states, oldest first, pruned to the last ``keep_s`` seconds."""

    def __init__(self, keep_s: float = 5.0) -> None:
        self.keep_s = float(keep_s)
        self._t: list[float] = []
        self._v: list[T] = []

    def append(self, t_s: float, value: T) -> None:
        if self._t and t_s < self._t[-1]:
            raise ValueError(f"timeline goes back in time: {t_s} < {self._t[-1]}")
        self._t.append(float(t_s))
        self._v.append(value)
        if len(self._t) > 4096 and self._t[-1] - self._t[0] > self.keep_s:
            cut = bisect.bisect_left(self._t, self._t[-1] - self.keep_s)
            del self._t[:cut]
            del self._v[:cut]

    def at(self, t_s: float) -> T:
        """The newest state recorded at or before ``t_s`` (the oldest kept if ``t_s`` is earlier)."""
        if not self._t:
            raise LookupError("empty timeline")
        i = bisect.bisect_right(self._t, t_s) - 1
        return self._v[max(0, i)]

    def time_at(self, t_s: float) -> float:
        """The time stamp of the state :meth:`at` returns for ``t_s``."""
        i = bisect.bisect_right(self._t, t_s) - 1
        return self._t[max(0, i)]

    def between(self, t0_s: float, t1_s: float) -> list[tuple[float, T]]:
        """The recorded (time, state) pairs with ``t0_s < t ≤ t1_s``."""
        i = bisect.bisect_right(self._t, t0_s)
        j = bisect.bisect_right(self._t, t1_s)
        return list(zip(self._t[i:j], self._v[i:j]))

    def latest(self) -> T:
        return self.at(float("inf"))
