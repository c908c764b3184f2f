"""Speed helpers shared by the trade topics: every setting timed in the same run, interleaved.

On a shared machine the load changes from second to second. Timing setting A for a while, then B,
lets a load spike land on one of them only; :func:`rates_per_s` instead runs the settings round by
round (A, B, C, then B, C, A, ...: each round one further on, so none always follows the same one)
and keeps each setting's best round, so every setting sees the same conditions and the figure is the
least disturbed one.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Hashable, Mapping, TypeVar

K = TypeVar("K", bound=Hashable)


def _one_round(fn: Callable[[], Any], min_time_s: float, min_calls: int) -> float:
    n = 0
    t0 = time.perf_counter()
    while True:
        fn()
        n += 1
        dt = time.perf_counter() - t0
        if n >= min_calls and dt >= min_time_s:
            return n / dt


def rates_per_s(fns: Mapping[K, Callable[[], Any]], *, rounds: int = 3, min_time_s: float = 0.2,
                min_calls: int = 2, warmup: bool = True) -> dict[K, float]:
    """Calls per second of each zero-argument callable: the best of ``rounds`` interleaved rounds.

    Each round calls a callable at least ``min_calls`` times and for at least ``min_time_s``
    seconds. ``warmup`` calls each once first (caches, lazy imports, JIT-compiled kernels).
    """
    if rounds < 1:
        raise ValueError(f"rounds={rounds} must be >= 1")
    if min_time_s < 0 or min_calls < 1:
        raise ValueError(f"min_time_s={min_time_s} must be >= 0 s and min_calls={min_calls} >= 1")
    if warmup:
        for fn in fns.values():
            fn()
    best: dict[K, float] = {k: 0.0 for k in fns}
    items = list(fns.items())
    for r in range(rounds):
        # Each round starts one setting further on, so no setting always follows the same one (with a
        # fixed order one registration setting reads ~7 % under others running the very same work).
        for k, fn in items[r % len(items):] + items[:r % len(items)]:
            best[k] = max(best[k], _one_round(fn, min_time_s, min_calls))
    return best


def rate_per_s(fn: Callable[[], Any], **kwargs: Any) -> float:
    """Calls per second of one callable (see :func:`rates_per_s`)."""
    return rates_per_s({0: fn}, **kwargs)[0]
